"""Our registration time against KISS-Matcher + small_gicp GICP, in one process.

The fastest generic peer we know: KISS-Matcher (``KISSMatcherConfig(0.1)``,
``estimate`` on float32 arrays) for the coarse pose, then small_gicp's GICP
(``downsampling_resolution=0.02``, ``max_correspondence_distance=0.2``, two threads).
:func:`kiss_ratio` runs it and ``amrst.register`` on the same clouds (local frame,
already in memory), the peer before and after ours, and keeps the peer's faster
run: the ratio is our compute time (``timings["total"]`` without the metrics stage)
over the peer's. The peer's inputs are checked for its libraries
(:func:`peer_input`) before its clock starts. ``kiss-matcher`` is a dependency
where it has wheels (Linux x86_64, macOS arm64).
"""

from __future__ import annotations

import logging
import time
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from amrst.errors import InvalidInput
from amrst.guards import ShiftedPair, grid_pair, kiss_pair

logger = logging.getLogger(__name__)

if TYPE_CHECKING:
    from collections.abc import Sequence
    from pathlib import Path

    from amrst.progress import Reporter
    from amrst.types import Transform


@dataclass(frozen=True, slots=True)
class KissRow:
    """One case: both methods' compute times and truth errors."""

    case: str
    ours_s: float
    kiss_s: float
    ours_rot_deg: float
    ours_gt_rmse_m: float
    kiss_rot_deg: float
    kiss_gt_rmse_m: float

    @property
    def ratio(self) -> float:
        """Our time over the peer's (below 1: we are faster)."""
        return self.ours_s / self.kiss_s


#: The peer's settings: KISS-Matcher's voxel, then GICP's voxel and distance (m).
KISS_VOXEL_M, GICP_VOXEL_M, GICP_MAX_DIST_M = 0.1, 0.02, 0.2


@dataclass(frozen=True, slots=True)
class PeerInput:
    """Two local clouds checked for the peer's compiled libraries.

    ``pair`` lies within small_gicp's voxel grid (so within KISS-Matcher's coarser
    one too); ``kiss_runs`` is False where KISS-Matcher would find no feature point
    and end the process: GICP then starts from the identity.
    """

    pair: ShiftedPair
    kiss_runs: bool


def peer_input(target_xyz: np.ndarray, source_xyz: np.ndarray) -> PeerInput:
    """Check and move two local clouds for :func:`kiss_gicp` (outside its timing).

    Raises
    ------
    InvalidInput
        An empty cloud, NaN/inf coordinates, or a span the voxel grids cannot hold.
    """
    import kiss_matcher

    pair = grid_pair(target_xyz, source_xyz, GICP_VOXEL_M)
    radius = kiss_matcher.KISSMatcherConfig(KISS_VOXEL_M).normal_radius
    features = kiss_pair(pair.target, pair.source, KISS_VOXEL_M, radius)
    return PeerInput(pair, features is not None)


def kiss_gicp(peer: PeerInput) -> Transform:
    """KISS-Matcher, then small_gicp GICP: ``T_target_source`` of two local clouds."""
    import kiss_matcher
    import small_gicp

    pair = peer.pair
    T = np.eye(4)
    if peer.kiss_runs:
        config = kiss_matcher.KISSMatcherConfig(KISS_VOXEL_M)
        sol = kiss_matcher.KISSMatcher(config).estimate(
            pair.source.astype(np.float32), pair.target.astype(np.float32)
        )
        T[:3, :3] = np.asarray(sol.rotation)
        T[:3, 3] = np.asarray(sol.translation).ravel()
    out = small_gicp.align(
        pair.target,
        pair.source,
        T,
        registration_type="GICP",
        downsampling_resolution=GICP_VOXEL_M,
        max_correspondence_distance=GICP_MAX_DIST_M,
        num_threads=2,
    )
    return pair.unshift(out.T_target_source)


def kiss_case_paths(
    cases_dirs: Sequence[str], pattern: str | None = None
) -> list[Path]:
    """Return the case folders :func:`kiss_ratio` times, checked before any work.

    Raises
    ------
    InvalidInput
        If kiss-matcher is not installed, or a folder is missing or holds no case.
    """
    try:
        import kiss_matcher  # noqa: F401
    except ImportError:
        raise InvalidInput(
            "The KISS-Matcher comparison needs the kiss-matcher package: "
            "pip install kiss-matcher (wheels for Linux x86_64 and macOS arm64)."
        ) from None
    from amrst.io.cases import find_cases

    paths = []
    for d in cases_dirs:
        found = find_cases(d, pattern)
        if not found:
            raise InvalidInput(
                f"No case folders (with truth.json) under {d}: give --kiss the "
                "folders that hold them."
            )
        paths += found
    return paths


def kiss_ratio(
    cases_dirs: Sequence[str],
    pattern: str | None = None,
    reporter: Reporter | None = None,
) -> list[KissRow]:
    """Time both methods on every case of ``cases_dirs``.

    Returns
    -------
    list of KissRow
        A case our pipeline refuses (no verified candidate) is timed all the same; a
        case that cannot be read is skipped with a warning, as ``amrst bench`` does.
    """
    from amrst.baselines._common import local_pair, to_local
    from amrst.errors import RegistrationFailed
    from amrst.io.cases import read_case
    from amrst.pipeline import register
    from amrst.stages.metrics import truth_errors

    paths = kiss_case_paths(cases_dirs, pattern)
    rows: list[KissRow] = []
    for n, path in enumerate(paths):
        if reporter is not None:
            reporter.progress(n / len(paths), path.name)
        try:
            case = read_case(path)
        except InvalidInput as exc:
            logger.warning("%s skipped: %s", path.name, exc)
            continue
        tgt, src, origin = local_pair(case.target, case.source)
        peer = peer_input(tgt, src)
        if not rows:  # load both libraries and warm their code paths first
            kiss_gicp(peer)
            register(case.target, case.source)
        kiss_times = []
        t0 = time.perf_counter()
        T_kiss = kiss_gicp(peer)
        kiss_times.append(time.perf_counter() - t0)
        try:
            res = register(case.target, case.source)
            ours = res.timings["total"] - res.timings.get("metrics", 0.0)
            T_ours = to_local(res.T_target_source, origin)
        except RegistrationFailed:
            ours, T_ours = float("nan"), np.full((4, 4), np.nan)
        t0 = time.perf_counter()
        kiss_gicp(peer)
        kiss_times.append(time.perf_counter() - t0)
        T_true = to_local(case.T_target_source, origin)
        e_ours = truth_errors(T_ours, T_true, src)
        e_kiss = truth_errors(T_kiss, T_true, src)
        rows.append(
            KissRow(
                path.name,
                ours,
                min(kiss_times),
                e_ours.rotation_error_deg,
                e_ours.gt_rmse_m,
                e_kiss.rotation_error_deg,
                e_kiss.gt_rmse_m,
            )
        )
    return rows


def format_kiss_table(rows: Sequence[KissRow]) -> str:
    """Format the rows as Markdown, with the median ratio under the table."""
    lines = [
        "| case | ours s | KISS+GICP s | ratio | ours rot deg / gt_rmse cm | KISS rot deg / gt_rmse cm |",
        "|---|---|---|---|---|---|",
    ]
    for r in rows:
        lines.append(
            f"| {r.case} | {r.ours_s:.3f} | {r.kiss_s:.3f} | {r.ratio:.2f} | "
            f"{r.ours_rot_deg:.3f} / {100 * r.ours_gt_rmse_m:.2f} | "
            f"{r.kiss_rot_deg:.3f} / {100 * r.kiss_gt_rmse_m:.2f} |"
        )
    ours = np.array([r.ours_s for r in rows])
    kiss = np.array([r.kiss_s for r in rows])
    ok = np.isfinite(ours)
    lines.append("")
    lines.append(
        f"Median time: ours {np.median(ours[ok]):.3f} s, KISS-Matcher + GICP "
        f"{np.median(kiss[ok]):.3f} s; ratio of medians "
        f"{np.median(ours[ok]) / np.median(kiss[ok]):.2f}, median of per-case ratios "
        f"{np.median(ours[ok] / kiss[ok]):.2f} ({int(ok.sum())} cases)."
    )
    return "\n".join(lines)
