"""Cloud-to-cloud distances on what both scans saw.

Distances over everything in two field scans mostly measure what only one of them
saw: the far side of the stem, the ground behind a neighbour, a shrub. A right
registration then reads as centimetres off. Here the distances are taken only where
both scans have points: source points (moved) whose voxel the target also occupies,
on the points above the ground the scene stage kept (the scene is rigid, so a
neighbour both scans saw is evidence too). No Qt, no pyvista.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from amrst.stages.voxels import voxel_grid

#: The overlap's voxel: near the spacing of a tree scan's stem at 5-10 m, coarse
#: enough that both scans' samples of one surface share it.
OVERLAP_VOXEL_M = 0.1
WITHIN_M = 0.02


@dataclass(frozen=True, slots=True)
class OverlapDistances:
    """Distances from the moved source to the target where both scans saw the scene.

    Attributes
    ----------
    median_m : float
        Median distance over the overlap (NaN when there is none).
    p95_m : float
        95th percentile over the overlap.
    within_2cm_fraction : float
        Share of overlap points within 2 cm of the target.
    overlap_fraction : float
        Share of the source's points that lie in the overlap.
    n_points_measured : int
        Source points in the overlap, the distances were measured on.
    """

    median_m: float
    p95_m: float
    within_2cm_fraction: float
    overlap_fraction: float
    n_points_measured: int

    def as_dict(self) -> dict[str, float]:
        """Return the figures by name, as in ``metrics.json``'s ``quality.distance``."""
        return {
            "median_m": self.median_m,
            "p95_m": self.p95_m,
            "within_2cm_fraction": self.within_2cm_fraction,
            "overlap_fraction": self.overlap_fraction,
            "n_points_measured": float(self.n_points_measured),
        }


def overlap_distances(
    target_xyz: np.ndarray,
    source_xyz: np.ndarray,
    T_target_source: np.ndarray,
    voxel_m: float = OVERLAP_VOXEL_M,
) -> OverlapDistances:
    """Measure the distances from the moved source to the target in their overlap.

    Parameters
    ----------
    target_xyz, source_xyz : (N, 3), (M, 3) float64
        Both scans in their own local frames (the tree of interest).
    T_target_source : (4, 4) float64
    voxel_m : float
        Side of the voxels that decide what both scans saw.

    Returns
    -------
    OverlapDistances
    """
    from scipy.spatial import cKDTree

    nan = float("nan")
    if len(target_xyz) == 0 or len(source_xyz) == 0:
        return OverlapDistances(nan, nan, nan, 0.0, 0)
    T = np.asarray(T_target_source, float)
    moved = np.asarray(source_xyz, float) @ T[:3, :3].T + T[:3, 3]
    target = np.asarray(target_xyz, float)
    code = voxel_grid(np.vstack([target, moved]), voxel_m)[1]
    both = np.isin(code[len(target) :], code[: len(target)])
    if not both.any():
        return OverlapDistances(nan, nan, nan, 0.0, 0)
    d = cKDTree(target).query(moved[both])[0]
    return OverlapDistances(
        median_m=float(np.median(d)),
        p95_m=float(np.percentile(d, 95)),
        within_2cm_fraction=float(np.mean(d <= WITHIN_M)),
        overlap_fraction=float(both.mean()),
        n_points_measured=int(both.sum()),
    )
