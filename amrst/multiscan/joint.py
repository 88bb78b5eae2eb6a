"""Joint refinement of every scan's pose: a multi-view ICP.

Composing pairwise transforms along the spanning tree adds their errors up. Here each
non-reference scan is refined in turn against *all* the other reached scans together
(posed as they currently are), for a few rounds (Gauss-Seidel multi-view ICP, as in
Pulli's "Multiview registration for large data sets"): a scan that overlaps little
with the reference is held by every scan around it, and loops close.

The refinement is kept when it does not raise the error of the poses (by default the
mean NN-RMSE between each scan and the others in their overlap); otherwise the tree's
poses stay (reported in the result).
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import TYPE_CHECKING

import numpy as np

from amrst.neighbours import THREADS
from amrst.progress import NULL_REPORTER, Reporter
from amrst.types import apply_transform

if TYPE_CHECKING:
    from collections.abc import Callable, Sequence

    from amrst.params import RegistrationParams
    from amrst.pipeline import ScanAnalysis
    from amrst.stages.fine import FineParams, FineResult
    from amrst.types import Transform

#: Rounds over all scans; the second one settles what the first moved.
ROUNDS = 2
#: Largest correspondence distance of the joint ICP (m): the poses are already close.
JOINT_MAX_CORR_M = 0.05
#: Points of the joint ICP: all preprocessed points (the leaf points alone leave too
#: little overlap to lower the mutual NN-RMSE, so the refinement would be rejected).
JOINT_POINTS = "all"


@dataclass(frozen=True, slots=True)
class JointResult:
    """Poses after the joint refinement and whether it was kept.

    ``rmse_before_m`` / ``rmse_after_m``: the error it is judged by, before and after:
    by default the mean over scans of the NN-RMSE of each scan against all the others,
    within the metrics' overlap distance (``refine_jointly``'s ``error``).
    ``moved_m[k]``: how far the refinement moved scan k (largest shift of its points).
    """

    poses: tuple[Transform | None, ...]
    kept: bool
    rounds: int
    rmse_before_m: float
    rmse_after_m: float
    moved_m: tuple[float, ...]

    def as_dict(self) -> dict[str, object]:
        """Plain numbers for JSON."""
        return {
            "kept": self.kept,
            "rounds": self.rounds,
            "rmse_before_m": self.rmse_before_m,
            "rmse_after_m": self.rmse_after_m,
            "moved_m": list(self.moved_m),
        }


def _posed(
    points: Sequence[np.ndarray], poses: Sequence[Transform | None], k: int
) -> np.ndarray:
    """Return every reached scan but k, posed, as one (M, 3) array."""
    parts = [
        apply_transform(pose, pts)
        for m, (pts, pose) in enumerate(zip(points, poses, strict=True))
        if m != k and pose is not None
    ]
    return np.vstack(parts) if parts else np.zeros((0, 3))


def mutual_rmse(
    points: Sequence[np.ndarray],
    poses: Sequence[Transform | None],
    overlap_m: float,
) -> float:
    """Return the mean over reached scans of their NN-RMSE to the others, in the overlap."""
    from scipy.spatial import cKDTree

    values = []
    for k, pose in enumerate(poses):
        if pose is None:
            continue
        others = _posed(points, poses, k)
        if len(others) == 0:
            continue
        d = cKDTree(others).query(apply_transform(pose, points[k]), k=1)[0]
        d = d[d <= overlap_m]
        if len(d):
            values.append(float(np.sqrt(np.mean(d**2))))
    return float(np.mean(values)) if values else float("nan")


def _moved(before: Transform, after: Transform, pts: np.ndarray) -> float:
    if len(pts) == 0:
        return 0.0
    diff = apply_transform(before, pts) - apply_transform(after, pts)
    return float(np.sqrt((diff**2).sum(axis=1)).max())


def refine_jointly(
    analyses: Sequence[ScanAnalysis],
    poses: Sequence[Transform | None],
    reference: int,
    params: RegistrationParams,
    reporter: Reporter = NULL_REPORTER,
    *,
    threads: int = THREADS,
    error: Callable[[Sequence[Transform | None]], float] | None = None,
) -> JointResult:
    """Refine every reached non-reference pose against all the other scans.

    The refinement is kept when it does not raise ``error`` (the poses' error; by
    default :func:`mutual_rmse` of the scans' points).

    Parameters
    ----------
    analyses : sequence of ScanAnalysis
        The scans, analysed once.
    poses : sequence of (4, 4) float64 or None
        Each scan's local frame -> the reference's local frame (None: not reached).
    reference : int
        Its pose stays the identity.
    params : RegistrationParams
        ``fine`` settings (voxel size, method, iterations) and the overlap distance;
        the point set is ``JOINT_POINTS``.
    reporter : Reporter
    threads : int
        Threads for the KD-tree queries.
    error : callable or None
        The error of a set of poses (m).

    Returns
    -------
    JointResult
    """
    from threadpoolctl import threadpool_limits

    from amrst.stages.fine import refine_registration

    fine = replace(
        params.fine,
        max_corr_dist_m=min(params.fine.max_corr_dist_m, JOINT_MAX_CORR_M),
        min_corr_dist_m=min(params.fine.min_corr_dist_m, JOINT_MAX_CORR_M),
    )
    if fine.method == "none":
        fine = replace(fine, method="lm_icp")
    points = [an.points(JOINT_POINTS) for an in analyses]
    overlap = params.metrics.overlap_dist_m
    current = list(poses)
    movable = [k for k, p in enumerate(current) if p is not None and k != reference]
    judge = error or (lambda poses: mutual_rmse(points, poses, overlap))
    before = judge(current)
    # One BLAS thread: the ICP's large sums then add up in one order, so the poses are
    # the same bit for bit whatever BLAS threads the process has (the CLI's threaded
    # BLAS, a Dask worker's one thread).
    with threadpool_limits(limits=1, user_api="blas"):
        current = _rounds(
            points,
            current,
            movable,
            fine,
            rounds=ROUNDS,
            reporter=reporter,
            refine_registration=refine_registration,
            threads=threads,
        )
    after = judge(current)
    kept = bool(np.isfinite(after) and (not np.isfinite(before) or after <= before))
    final = tuple(current) if kept else tuple(poses)
    moved = tuple(
        0.0 if p is None or q is None else _moved(p, q, points[k])
        for k, (p, q) in enumerate(zip(poses, final, strict=True))
    )
    return JointResult(final, kept, ROUNDS, before, after, moved)


def _rounds(
    points: list[np.ndarray],
    current: list[Transform | None],
    movable: list[int],
    fine: FineParams,
    *,
    rounds: int,
    reporter: Reporter,
    refine_registration: Callable[..., FineResult],
    threads: int,
) -> list[Transform | None]:
    """Refine each movable scan against all the others, ``rounds`` times over."""
    steps = max(1, rounds * len(movable))
    done = 0
    for _ in range(rounds):
        for k in movable:
            reporter.check_cancelled()
            start = current[k]
            assert start is not None  # movable scans are reached
            result = refine_registration(  # keywords: the order changed once
                target_xyz=_posed(points, current, k),
                source_xyz=points[k],
                T_init=start,
                params=fine,
                threads=threads,
            )
            current[k] = result.T_target_source
            done += 1
            reporter.progress(done / steps, "joint refinement")
    return current
