"""Preprocess: drop NaNs, remove statistical outliers, thin to a voxel grid.

Thinning only evens out density (near points are dense in TLS scans); every later stage
keeps indices into the original cloud so that exports never lose points.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field

import numpy as np

from amrst.errors import InvalidInput
from amrst.progress import NULL_REPORTER, Reporter

log = logging.getLogger(__name__)


@dataclass(frozen=True, slots=True, kw_only=True)
class PreprocessParams:
    """Noise filtering and thinning."""

    outlier_neighbours: int = field(
        default=12,
        metadata={
            "unit": "points",
            "min": 0,
            "max": 100,
            "help": "Neighbours used by the statistical outlier filter; 0 turns it off. Typical 8-30.",
        },
    )
    outlier_std_ratio: float = field(
        default=3.0,
        metadata={
            "unit": "σ",
            "min": 0.5,
            "max": 10.0,
            "help": "A point whose mean neighbour distance is more than this many standard deviations above the average is noise. Typical 2-4.",
        },
    )
    voxel_size_m: float = field(
        default=0.03,
        metadata={
            "unit": "m",
            "min": 0.0,
            "max": 0.5,
            "help": "Thin to one point per voxel of this size before analysis (0 = keep all). Typical 0.01-0.05.",
        },
    )
    max_points: int = field(
        default=120_000,
        metadata={
            "unit": "points",
            "min": 1000,
            "max": 10_000_000,
            "help": "Largest working set: a bigger scan is thinned with a larger voxel until this many points remain (logged). Keeps huge scans to seconds; exports always use every point.",
        },
    )
    min_points: int = field(
        default=200,
        metadata={
            "unit": "points",
            "min": 10,
            "max": 100000,
            "help": "Fewest points a scan must keep to be registered.",
        },
    )

    def __post_init__(self) -> None:
        if (
            self.outlier_neighbours < 0
            or self.outlier_std_ratio <= 0
            or self.voxel_size_m < 0
        ):
            raise ValueError(
                "preprocess parameters must be non-negative (std ratio > 0)"
            )
        if self.min_points > self.max_points:
            raise ValueError(
                f"preprocess.min_points ({self.min_points}) must be at most "
                f"preprocess.max_points ({self.max_points}); lower one or raise the other"
            )


@dataclass(frozen=True, slots=True)
class PreprocessResult:
    """What was kept, as indices into the input cloud."""

    xyz: np.ndarray  # (N, 3) float64 kept (thinned) points, local coordinates
    index: np.ndarray  # (N,) int64 index of each kept point in the input cloud
    n_input: int
    n_invalid: int  # NaN/inf coordinates dropped
    n_outliers: int  # removed by the statistical filter
    n_thinned: int  # merged away by voxel thinning


def voxel_grid(xyz: np.ndarray, voxel: float) -> tuple[np.ndarray, np.ndarray]:
    """Integer voxel of each point, and one int64 code per voxel (for a fast 1-D unique).

    Returns
    -------
    keys : (N, 3) int64, counted from the cloud's minimum corner
    code : (N,) int64, equal for points in the same voxel. Keys of up to 2^21 voxels per
        axis are packed into one int64; larger grids fall back to row-wise codes.
    """
    k = np.floor((xyz - xyz.min(axis=0)) / voxel).astype(np.int64)
    if k.size and k.max() < (1 << 21):
        return k, (k[:, 0] << 42) | (k[:, 1] << 21) | k[:, 2]
    return k, np.unique(k, axis=0, return_inverse=True)[1].ravel().astype(np.int64)


def _voxel_representatives(xyz: np.ndarray, voxel: float) -> np.ndarray:
    """Index of the point nearest each occupied voxel's centroid (keeps real points)."""
    return voxel_representatives(xyz, voxel)[0]


def voxel_representatives(
    xyz: np.ndarray, voxel: float
) -> tuple[np.ndarray, np.ndarray]:
    """One real point per occupied voxel: the one nearest the voxel's centroid.

    Parameters
    ----------
    xyz : (N, 3) float64
    voxel : float
        Voxel size (m).

    Returns
    -------
    reps : (V,) int64, sorted
        Index of each voxel's representative (ties go to the lowest index).
    owner : (N,) int64
        Position in ``reps`` of the representative of each point's voxel.
    """
    if len(xyz) == 0:
        return np.zeros(0, dtype=np.int64), np.zeros(0, dtype=np.int64)
    code = voxel_grid(xyz, voxel)[1]
    # One stable sort groups the points by voxel; within a voxel they stay in index
    # order, so the centroid sums run as a bincount over the unsorted points would.
    order = np.argsort(code, kind="stable")
    sorted_code = code[order]
    new = np.empty(len(order), dtype=bool)
    new[0] = True
    np.not_equal(sorted_code[1:], sorted_code[:-1], out=new[1:])
    group = np.cumsum(new) - 1  # voxel of each sorted point
    n = int(group[-1]) + 1
    pts = xyz[order]
    counts = np.bincount(group, minlength=n)
    centroids = np.column_stack([np.bincount(group, pts[:, d], n) for d in range(3)])
    dist = np.sum((pts - centroids[group] / counts[group, None]) ** 2, axis=1)
    nearest = np.minimum.reduceat(dist, np.flatnonzero(new))
    hit = np.flatnonzero(dist == nearest[group])  # sorted position, by voxel then index
    first = np.empty(len(hit), dtype=bool)
    first[0] = True
    np.not_equal(group[hit][1:], group[hit][:-1], out=first[1:])
    rep_of_group = order[hit[first]]
    by_index = np.argsort(rep_of_group)
    reps = rep_of_group[by_index]
    rank = np.empty(n, dtype=np.int64)
    rank[by_index] = np.arange(n)
    owner = np.empty(len(xyz), dtype=np.int64)
    owner[order] = rank[group]
    return reps, owner


def _statistical_inliers(pts: np.ndarray, k: int, std_ratio: float) -> np.ndarray:
    """Return indices of the points that pass Open3D's statistical outlier rule.

    A point passes when its mean distance to its k neighbours is at most
    mean + std_ratio * std over all points. Done in scipy: importing Open3D costs a
    second per command.
    """
    from scipy.spatial import cKDTree

    d = cKDTree(pts).query(pts, k=k + 1, workers=-1)[0][:, 1:].mean(axis=1)
    return np.flatnonzero(d <= d.mean() + std_ratio * d.std())


def preprocess_points(
    xyz: np.ndarray, params: PreprocessParams, reporter: Reporter = NULL_REPORTER
) -> PreprocessResult:
    """Filter noise and thin a scan.

    Parameters
    ----------
    xyz : (N, 3) float64
        Local coordinates of the scan.
    params : PreprocessParams
    reporter : Reporter

    Returns
    -------
    PreprocessResult

    Raises
    ------
    InvalidInput
        When fewer than ``params.min_points`` points survive.
    """
    n_input = len(xyz)
    index = np.flatnonzero(np.all(np.isfinite(xyz), axis=1))
    n_invalid = n_input - len(index)
    pts = xyz[index]
    reporter.check_cancelled()
    # Thin first: the outlier filter then works on even density (TLS scans are far
    # denser near the scanner) and costs a fraction.
    n_before = len(pts)
    if params.voxel_size_m > 0 and len(pts):
        reps = _voxel_representatives(pts, params.voxel_size_m)
        index, pts = index[reps], pts[reps]
    voxel = params.voxel_size_m
    while len(pts) > params.max_points:
        # Surface density falls with the square of the voxel size.
        voxel = max(voxel, 0.005) * max(1.2, np.sqrt(len(pts) / params.max_points))
        reps = _voxel_representatives(pts, voxel)
        index, pts = index[reps], pts[reps]
    if voxel != params.voxel_size_m:
        log.warning(
            "Large scan: thinned to %d points with a %.1f cm voxel (max_points %d).",
            len(pts),
            voxel * 100,
            params.max_points,
        )
    n_thinned = n_before - len(pts)
    reporter.progress(0.5, "thinned")
    n_outliers = 0
    if params.outlier_neighbours > 0 and len(pts) > params.outlier_neighbours + 1:
        kept = _statistical_inliers(
            pts, params.outlier_neighbours, params.outlier_std_ratio
        )
        n_outliers = len(pts) - len(kept)
        index, pts = index[kept], pts[kept]
    if len(pts) < params.min_points:
        raise InvalidInput(
            f"Only {len(pts)} usable point(s) after filtering ({n_input} read, {n_invalid} invalid, "
            f"{n_outliers} outliers); at least {params.min_points} are needed. Check that the file "
            "holds a whole tree scan, or lower the voxel size / outlier filter."
        )
    reporter.progress(1.0, f"{len(pts)} points kept")
    return PreprocessResult(pts, index, n_input, n_invalid, n_outliers, n_thinned)
