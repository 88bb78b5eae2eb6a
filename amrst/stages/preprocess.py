"""Preprocess: drop NaNs, remove statistical outliers, thin to a voxel grid.

Thinning only evens out density (near points are dense in TLS scans); every later stage
keeps indices into the original cloud so that exports never lose points.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np

from amrst.errors import InvalidInput
from amrst.neighbours import THREADS
from amrst.progress import NULL_REPORTER, Reporter
from amrst.stages.features import pairwise_rows
from amrst.stages.voxels import finite_rows, voxel_sample

if TYPE_CHECKING:
    from amrst.neighbours import NeighbourTable

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
    # The outlier filter's neighbour query, kept for the later stages (``share_k``):
    # a view of exactly the kept points. None when not asked for or not queried.
    neighbours: NeighbourTable | None = None


def _statistical_inliers(
    pts: np.ndarray, k: int, std_ratio: float, share_k: int, threads: int
) -> tuple[np.ndarray, NeighbourTable]:
    """Return indices of the points that pass Open3D's statistical outlier rule.

    A point passes when its mean distance to its k neighbours is at most
    mean + std_ratio * std over all points. Done without Open3D (importing it costs a
    second per command), on small_gicp's KD-tree (:func:`amrst.neighbours.knn`).
    The neighbour table (``max(k + 1, share_k)`` per point, a view of the inliers) is
    returned too: the sorted distances of a longer query begin with the same values.
    """
    from amrst.neighbours import NeighbourTable

    table = NeighbourTable.build(pts, max(k + 1, share_k), threads)
    # The mean of neighbours 1..k, i.e. ``dist[:, 1:k + 1].mean(axis=1)`` bit for bit,
    # summed as whole columns (numpy's per-row sum of k numbers is slow).
    d = pairwise_rows(table.knn(k + 1)[0][:, 1:].T[None])[0] / k
    kept = np.flatnonzero(d <= d.mean() + std_ratio * d.std())
    return kept, table.subset(kept)


def preprocess_points(
    xyz: np.ndarray,
    params: PreprocessParams,
    reporter: Reporter = NULL_REPORTER,
    share_k: int = 0,
    *,
    threads: int = THREADS,
) -> PreprocessResult:
    """Filter noise and thin a scan.

    Parameters
    ----------
    xyz : (N, 3) float64
        Local coordinates of the scan.
    params : PreprocessParams
    reporter : Reporter
    share_k : int
        When above 0 (and the outlier filter runs), its neighbour query lists this
        many neighbours and is kept in ``PreprocessResult.neighbours`` for the later
        stages (one query per scan instead of three).

    Returns
    -------
    PreprocessResult

    Raises
    ------
    InvalidInput
        When fewer than ``params.min_points`` points survive.
    """
    n_input = len(xyz)
    finite = finite_rows(xyz)
    if finite.all():  # the usual case: no copy of a scan of millions of points
        index, pts = np.arange(n_input), np.asarray(xyz)
    else:
        index = np.flatnonzero(finite)
        pts = xyz[index]
    n_invalid = n_input - len(index)
    reporter.check_cancelled()
    # Thin first: the outlier filter then works on even density (TLS scans are far
    # denser near the scanner) and costs a fraction.
    n_before = len(pts)
    if params.voxel_size_m > 0 and len(pts):
        reps = voxel_sample(pts, params.voxel_size_m)
        index, pts = index[reps], pts[reps]
    voxel = params.voxel_size_m
    while len(pts) > params.max_points:
        # Surface density falls with the square of the voxel size.
        voxel = max(voxel, 0.005) * max(1.2, np.sqrt(len(pts) / params.max_points))
        reps = voxel_sample(pts, voxel)
        index, pts = index[reps], pts[reps]
    if voxel != params.voxel_size_m:
        # Expected on any large scan (the progress line says "thinned"): not a warning.
        log.info(
            "Large scan: thinned to %d points with a %.1f cm voxel (max_points %d).",
            len(pts),
            voxel * 100,
            params.max_points,
        )
    n_thinned = n_before - len(pts)
    reporter.progress(0.5, "thinned")
    n_outliers = 0
    table = None
    if params.outlier_neighbours > 0 and len(pts) > params.outlier_neighbours + 1:
        kept, table = _statistical_inliers(
            pts, params.outlier_neighbours, params.outlier_std_ratio, share_k, threads
        )
        n_outliers = len(pts) - len(kept)
        index, pts = index[kept], pts[kept]
    if len(pts) < params.min_points:
        # Most points merged by the voxel grid: a scan in other units.
        hint = (
            f"{voxel:g} m cells keep {len(pts) + n_outliers} of them; are its "
            "coordinates in metres"
            if n_thinned > (n_input - n_invalid) / 2
            else "does the file hold a whole scan"
        )
        raise InvalidInput(
            f"Only {len(pts)} usable point(s) after filtering ({n_input} read, "
            f"{n_invalid} invalid, {n_thinned} merged in {voxel:g} m cells, "
            f"{n_outliers} outliers); at least {params.min_points} are needed: "
            f"{hint}?"
        )
    reporter.progress(1.0, f"{len(pts)} points kept")
    return PreprocessResult(
        pts,
        index,
        n_input,
        n_invalid,
        n_outliers,
        n_thinned,
        table if share_k > 0 else None,
    )
