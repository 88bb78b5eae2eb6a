"""Trunk-anchored yaw search: a second source of coarse candidates for levelled scans.

Beyond the paper. When no tetrahedron match verifies (the two skeletons share too
little, as when two scanners saw opposite halves of a crown), levelled scans still share
the trunk: its base fixes the translation and only the heading (yaw) is unknown. The
trunk centre of each scan is a circle fitted to a low horizontal slice (the centroid of
the visible arc would sit a trunk radius towards the scanner). The search turns the
source about the vertical in ``yaw_step_deg`` steps, polishes each start with a
levelled (yaw + translation) ICP, scores it by the share of source points that land
within ``score_dist_m`` of the target, and returns the best distinct solutions. The
pipeline then refines each of them with the fine stage; ``merge_trunk_solutions``
scores them as the coarse stage scores its candidates and adds them to the ranking.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np

from amrst.geometry import kasa_circle, yaw_rotation
from amrst.neighbours import THREADS
from amrst.progress import NULL_REPORTER, Reporter
from amrst.stages.coarse import (
    distinct_solutions,
)
from amrst.stages.polish import polish, weighted_centres
from amrst.types import Transform, make_transform

if TYPE_CHECKING:
    from scipy.spatial import cKDTree

TRUNK_MODES = ("fallback", "always", "off")
_MIN_SLICE_POINTS = 10
# Polished points per batch of headings in the sweep (36 headings x 600 points).
_BATCH_POINTS = 40_000


@dataclass(frozen=True, slots=True, kw_only=True)
class TrunkParams:
    """Trunk-anchored yaw search (levelled scanners only)."""

    mode: str = field(
        default="fallback",
        metadata={
            "choices": TRUNK_MODES,
            "help": "fallback: search only when no tetrahedron match verifies; always: add its solutions to every ranking; off: never.",
        },
    )
    slice_low_m: float = field(
        default=0.1,
        metadata={
            "unit": "m",
            "min": 0.0,
            "max": 5.0,
            "help": "Bottom of the trunk slice, above the lowest point of the scan.",
        },
    )
    slice_high_m: float = field(
        default=1.3,
        metadata={
            "unit": "m",
            "min": 0.1,
            "max": 10.0,
            "help": "Top of the trunk slice, above the lowest point (1.3 m is breast height).",
        },
    )
    yaw_step_deg: float = field(
        default=10.0,
        metadata={
            "unit": "deg",
            "min": 1.0,
            "max": 90.0,
            "help": "Step of the heading sweep; each start is polished, so steps up to about 10 deg still find the heading.",
        },
    )
    polish_dist_m: float = field(
        default=0.2,
        metadata={
            "unit": "m",
            "min": 0.02,
            "max": 2.0,
            "help": "Largest correspondence distance of the levelled polish of each start. Small keeps each start local; large lets crowns pull it into a wrong overlap.",
        },
    )
    voxel_m: float = field(
        default=0.1,
        metadata={
            "unit": "m",
            "min": 0.01,
            "max": 1.0,
            "help": "Voxel size of the clouds the sweep polishes on.",
        },
    )
    points: int = field(
        default=600,
        metadata={
            "unit": "points",
            "min": 50,
            "max": 100000,
            "help": "Source points sampled for the polish and the score of each start (seeded).",
        },
    )
    score_dist_m: float = field(
        default=0.015,
        metadata={
            "unit": "m",
            "min": 0.002,
            "max": 0.5,
            "help": "A source point scores when it lands this close to the target. Tight: only the true heading puts many points on surfaces both scanners saw.",
        },
    )
    keep: int = field(
        default=3,
        metadata={
            "unit": "solutions",
            "min": 1,
            "max": 36,
            "help": "Best distinct headings handed on to fine registration and the final choice.",
        },
    )
    fine_points: str = field(
        default="best",
        metadata={
            "choices": ("best", "all", "leaf", "wood"),
            "help": "Points the full fine registration of the best heading (and its contenders, see contender_share) uses. best: fit on all points and on the leaf points and keep the fit that puts more source points within score_dist_m (all points hold scans that share little crown in place; leaf points avoid the bias two trunk halves give).",
        },
    )
    refine_voxel_m: float = field(
        default=0.08,
        metadata={
            "unit": "m",
            "min": 0.0,
            "max": 0.5,
            "help": "Voxel size of the quick fine registration that ranks the kept headings; the best one and its contenders are then refined with the full fine settings.",
        },
    )
    refine_iterations: int = field(
        default=15,
        metadata={
            "unit": "",
            "min": 1,
            "max": 200,
            "help": "Iterations per scale of that quick fine registration.",
        },
    )
    contender_share: float = field(
        default=0.5,
        metadata={
            "unit": "of the best",
            "min": 0.0,
            "max": 1.0,
            "help": "Kept headings whose quick fit puts at least this share of the best one's close points (within score_dist_m) also get the full fine registration, and the best after it wins: a quick fit that has not converged does not decide between close contenders (1 = only the best and exact ties).",
        },
    )
    seed: int = field(
        default=0, metadata={"min": 0, "help": "Seed of the point sampling."}
    )

    def __post_init__(self) -> None:
        if self.mode not in TRUNK_MODES:
            raise ValueError(f"trunk mode must be one of {TRUNK_MODES}")
        if self.slice_low_m >= self.slice_high_m:
            raise ValueError(
                f"trunk.slice_low_m ({self.slice_low_m} m) must be below "
                f"trunk.slice_high_m ({self.slice_high_m} m); lower one or raise the other"
            )


@dataclass(frozen=True, slots=True)
class TrunkBase:
    """Where a scan's trunk meets the ground (its lowest points)."""

    centre: np.ndarray  # (3,) x, y of the trunk axis; z of the lowest point (m)
    radius_m: float  # fitted trunk radius; nan when the circle fit was not usable
    n_points: int  # points in the slice


@dataclass(frozen=True, slots=True)
class YawSolution:
    """One heading the yaw search settled on, with its score."""

    T_target_source: Transform  # levelled: rotation about the vertical only
    start_yaw_deg: float  # heading the sweep started from
    score: float  # share of sampled source points within score_dist_m


@dataclass(frozen=True, slots=True)
class TrunkSearchResult:
    """Both scans' trunk bases and the distinct yaw solutions found from them."""

    target_base: TrunkBase
    source_base: TrunkBase
    solutions: tuple[YawSolution, ...]  # best first, distinct


def find_trunk_base(xyz: np.ndarray, params: TrunkParams) -> TrunkBase:
    """Trunk centre from a circle fitted to a low slice of the scan.

    Parameters
    ----------
    xyz : (N, 3) float64
    params : TrunkParams

    Returns
    -------
    TrunkBase
        Falls back to the slice's median (radius nan) when the fit is unusable.
    """
    z0 = float(np.percentile(xyz[:, 2], 0.2))
    z = xyz[:, 2]
    sl = xyz[(z > z0 + params.slice_low_m) & (z < z0 + params.slice_high_m)]
    if len(sl) < _MIN_SLICE_POINTS:
        sl = xyz[z < z0 + params.slice_high_m]
    med = np.median(sl[:, :2], axis=0)
    centre, r2 = kasa_circle(sl[:, :2], med)
    radius = float(np.sqrt(r2)) if r2 > 0 else float("nan")
    spread = float(np.max(np.linalg.norm(sl[:, :2] - med, axis=1)))
    # A slice of branches or leaves fits a meaningless circle: keep the median then.
    if not np.isfinite(radius) or radius > max(1.5 * spread, 0.05) or radius > 2.0:
        return TrunkBase(np.r_[med, z0], float("nan"), len(sl))
    return TrunkBase(np.r_[centre, z0], radius, len(sl))


def _levelled_steps(p: np.ndarray, q: np.ndarray, w: np.ndarray) -> np.ndarray:
    """Fit q ≈ Rz p + t, a turn about the vertical only, for B point sets at once.

    Least squares under (B, n) 0/1 weights: a 2D Procrustes fit of the x, y offsets
    from the centroids, plus the centroid shift; (B, 4, 4).
    """
    pc, qc, a, b = weighted_centres(p, q, w)
    yaw = np.arctan2(
        np.einsum("bn,bn->b", w, a[..., 0] * b[..., 1] - a[..., 1] * b[..., 0]),
        np.einsum("bn,bn->b", w, a[..., 0] * b[..., 0] + a[..., 1] * b[..., 1]),
    )
    c, s = np.cos(yaw), np.sin(yaw)
    out = np.tile(np.eye(4), (len(p), 1, 1))
    out[:, 0, 0], out[:, 0, 1], out[:, 1, 0], out[:, 1, 1] = c, -s, s, c
    out[:, :3, 3] = qc - np.einsum("bij,bj->bi", out[:, :3, :3], pc)
    return out


def polish_levelled(
    src: np.ndarray, tgt: np.ndarray, tree: cKDTree, Ts: np.ndarray, max_dist: float
) -> np.ndarray:
    """Polish (B, 4, 4) starts at once with a turn about the vertical and a translation.

    The coarse stage's polish ICP, so restricted. ``tree`` is a cKDTree on ``tgt``.
    """
    return polish(src, tgt, tree, Ts, max_dist, fit=_levelled_steps, iterations=15)


def search_yaw(
    target_xyz: np.ndarray,
    source_xyz: np.ndarray,
    params: TrunkParams,
    reporter: Reporter = NULL_REPORTER,
    target_tree: cKDTree | None = None,
    *,
    threads: int = THREADS,
) -> TrunkSearchResult:
    """Sweep the source heading about its trunk base and keep the best distinct fits.

    Parameters
    ----------
    target_xyz, source_xyz : (N, 3), (M, 3) float64
        Preprocessed scans in their local frames.
    params : TrunkParams
    reporter : Reporter
    target_tree : cKDTree or None
        A tree on ``target_xyz``, reused when given.
    threads : int
        Threads for the KD-tree queries.

    Returns
    -------
    TrunkSearchResult
        Up to ``params.keep`` solutions, best first; they differ by > 5 deg or > 0.5 m.
    """
    from scipy.spatial import cKDTree

    from amrst.neighbours import NearestTree
    from amrst.stages.voxels import voxel_sample

    rng = np.random.default_rng(params.seed)
    tb = find_trunk_base(target_xyz, params)
    sb = find_trunk_base(source_xyz, params)
    tgt = target_xyz[voxel_sample(target_xyz, params.voxel_m)]
    src = source_xyz[voxel_sample(source_xyz, params.voxel_m)]
    if len(src) > params.points:
        src = src[rng.choice(len(src), params.points, replace=False)]
    sample = source_xyz[
        rng.choice(len(source_xyz), min(params.points, len(source_xyz)), replace=False)
    ]
    tree = NearestTree(tgt, threads)
    full_tree = cKDTree(target_xyz) if target_tree is None else target_tree
    yaws = np.arange(0.0, 360.0, params.yaw_step_deg)
    starts = np.stack(
        [
            make_transform(R, tb.centre - R @ sb.centre)
            for R in (yaw_rotation(np.radians(y)) for y in yaws)
        ]
    )
    # Headings in batches of at most _BATCH_POINTS polished points: one KD-tree query
    # per iteration serves the whole batch, and the partners each start keeps (the
    # polish's NearestCache) spare most queries; scoring a batch at once holds
    # batch x points x 3 floats, bounded whatever the step and sample size.
    found = []
    per = max(1, _BATCH_POINTS // max(len(src), len(sample), 1))
    for b0 in range(0, len(starts), per):
        reporter.check_cancelled()
        Ts = polish_levelled(
            src, tgt, tree, starts[b0 : b0 + per], params.polish_dist_m
        )
        moved = sample @ Ts[:, :3, :3].transpose(0, 2, 1) + Ts[:, None, :3, 3]
        d = full_tree.query(
            moved.reshape(-1, 3), distance_upper_bound=params.score_dist_m
        )[0].reshape(len(Ts), -1)
        for k, T in enumerate(Ts):
            score = float(np.mean(d[k] < params.score_dist_m))
            found.append(YawSolution(T, float(yaws[b0 + k]), score))
        reporter.progress(len(found) / len(starts), "trunk heading search")
    found.sort(key=lambda s: -s.score)
    centre = source_xyz.mean(axis=0)
    kept: list[YawSolution] = []
    for s in found:
        if all(
            distinct_solutions(s.T_target_source, k.T_target_source, centre)
            for k in kept
        ):
            kept.append(s)
            if len(kept) == params.keep:
                break
    return TrunkSearchResult(tb, sb, tuple(kept))
