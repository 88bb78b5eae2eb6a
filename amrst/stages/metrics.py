"""Registration quality: nearest-neighbour RMSE, Hausdorff distance, overlap, truth errors.

The paper scores with RMSE and the Hausdorff distance (section II.F). We report both,
in the overlap and overall, plus the 95th percentile of the Hausdorff distances (the
maximum alone is ruled by one stray point) and, when the truth is known, the rotation
and translation errors and ``gt_rmse``.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field

import numpy as np

from amrst.neighbours import THREADS
from amrst.sampling import random_rows
from amrst.types import Transform, rotation_angle_deg


@dataclass(frozen=True, slots=True, kw_only=True)
class MetricsParams:
    """How the distances are measured.

    overlap_dist_m : a source point whose nearest target point is closer than this is
        in the overlap (m). Typical 0.05-0.2.
    max_points : points sampled from each cloud for the distances (speed; seeded).
    """

    overlap_dist_m: float = field(
        default=0.1,
        metadata={
            "unit": "m",
            "min": 0.001,
            "max": 5.0,
            "help": "A source point closer than this to the target is in the overlap (RMSE in overlap, overlap fraction). Typical 0.05-0.2.",
        },
    )
    max_points: int = field(
        default=50_000,
        metadata={
            "unit": "points",
            "min": 100,
            "max": 10_000_000,
            "help": "Points sampled from each scan for the distance metrics (seeded).",
        },
    )
    seed: int = field(
        default=0, metadata={"min": 0, "help": "Seed of the metric sampling."}
    )

    def __post_init__(self) -> None:
        if self.overlap_dist_m <= 0:
            raise ValueError("overlap_dist_m must be > 0")
        if self.max_points < 1:
            raise ValueError("max_points must be >= 1")


@dataclass(frozen=True, slots=True)
class CloudMetrics:
    """Distances between the target and the moved source (metres)."""

    rmse_m: float  # RMS of source->target NN distances, all points
    rmse_overlap_m: float  # the same, only points within overlap_dist_m
    hausdorff_m: float  # symmetric Hausdorff distance (max of both directions)
    hausdorff_p95_m: float  # 95th percentile of the symmetric NN distances
    overlap_fraction: (
        float  # share of source points within overlap_dist_m of the target
    )
    n_target: int
    n_source: int

    def as_dict(self) -> dict[str, float]:
        """Plain dict for JSON/CSV."""
        return asdict(self)


#: The benchmark's rule: a pose is registered within this turn and RMS error.
REGISTERED_DEG = 1.0
REGISTERED_RMSE_M = 0.05


@dataclass(frozen=True, slots=True)
class TruthErrors:
    """Errors of an estimated transform against a known one."""

    rotation_error_deg: float
    translation_error_m: float
    gt_rmse_m: float  # RMS distance of source points mapped by estimate vs truth

    def registered(
        self,
        max_rot_deg: float = REGISTERED_DEG,
        max_gt_rmse_m: float = REGISTERED_RMSE_M,
    ) -> bool:
        """Apply the benchmark's success rule: rotation < 1 deg and gt_rmse < 5 cm."""
        return self.rotation_error_deg < max_rot_deg and self.gt_rmse_m < max_gt_rmse_m

    def as_dict(self) -> dict[str, float]:
        """Plain dict for JSON/CSV."""
        return asdict(self)


def measure_clouds(
    target_xyz: np.ndarray,
    moved_source_xyz: np.ndarray,
    params: MetricsParams = MetricsParams(),
    *,
    threads: int = THREADS,
) -> CloudMetrics:
    """Nearest-neighbour distances between two clouds already in one frame.

    Parameters
    ----------
    target_xyz : (N, 3) float64
    moved_source_xyz : (M, 3) float64
        Source points mapped into the target frame.
    params : MetricsParams
    threads : int
        Threads for the KD-tree queries.

    Returns
    -------
    CloudMetrics
    """
    from amrst.neighbours import NearestTree

    rng = np.random.default_rng(params.seed)
    tgt = random_rows(np.asarray(target_xyz, float), params.max_points, rng)
    src = random_rows(np.asarray(moved_source_xyz, float), params.max_points, rng)
    if len(tgt) == 0 or len(src) == 0:
        nan = float("nan")
        return CloudMetrics(nan, nan, nan, nan, 0.0, len(tgt), len(src))
    d_st = NearestTree(tgt, threads).query(src)[0]
    d_ts = NearestTree(src, threads).query(tgt)[0]
    inside = d_st < params.overlap_dist_m
    both = np.concatenate([d_st, d_ts])
    return CloudMetrics(
        rmse_m=float(np.sqrt(np.mean(d_st**2))),
        rmse_overlap_m=float(np.sqrt(np.mean(d_st[inside] ** 2)))
        if inside.any()
        else float("nan"),
        hausdorff_m=float(max(d_st.max(), d_ts.max())),
        hausdorff_p95_m=float(np.percentile(both, 95)),
        overlap_fraction=float(inside.mean()),
        n_target=len(target_xyz),
        n_source=len(moved_source_xyz),
    )


def truth_errors(
    T_estimate: Transform, T_truth: Transform, source_xyz: np.ndarray
) -> TruthErrors:
    """Compare an estimated ``T_target_source`` with the true one.

    Parameters
    ----------
    T_estimate, T_truth : (4, 4) float64
    source_xyz : (M, 3) float64
        Source points (source frame) over which ``gt_rmse`` is taken.

    Returns
    -------
    TruthErrors
    """
    R_delta = T_estimate[:3, :3] @ T_truth[:3, :3].T
    return TruthErrors(
        rotation_error_deg=rotation_angle_deg(R_delta),
        translation_error_m=float(np.linalg.norm(T_estimate[:3, 3] - T_truth[:3, 3])),
        gt_rmse_m=_gt_rmse(T_estimate, T_truth, source_xyz),
    )


def _gt_rmse(T_a: Transform, T_b: Transform, xyz: np.ndarray) -> float:
    """RMS of |T_a p - T_b p| over the points, from their mean and covariance.

    With A = R_a - R_b, b = t_a - t_b and p = c + q (c the mean): the mean of
    |A p + b|² is tr(A C Aᵀ) + |A c + b|², C the covariance of q. One pass over a
    multi-million-point scan instead of moving it twice; centring
    first keeps georeferenced coordinates exact.
    """
    pts = np.asarray(xyz, dtype=np.float64)
    if len(pts) == 0:
        return 0.0
    A = T_a[:3, :3] - T_b[:3, :3]
    b = T_a[:3, 3] - T_b[:3, 3]
    c = pts.mean(axis=0)
    q = pts - c
    C = (q.T @ q) / len(pts)
    e = A @ c + b
    return float(np.sqrt(max(float(np.trace(A @ C @ A.T)) + float(e @ e), 0.0)))
