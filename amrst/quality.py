"""What the technician judges a registration by: distances and stem slices.

Cloud-to-cloud distances both ways (CloudCompare's check) and horizontal stem slices
with the fitted circle of each scan and the offset between the centres (the
forester's own check: stems must overlap in every slice). Used by the app's quality
views and by the registration report. No Qt, no pyvista.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from amrst.measure import MeasureParams, StemCircle, fit_stem_circle

DEFAULT_HEIGHTS_M = (0.3, 1.3, 3.0)
DEFAULT_THICKNESS_M = 0.1
_STEM_RADIUS_M = 1.5  # slice points farther than this from the stem axis are crown


def nn_distances(
    a: np.ndarray, b: np.ndarray, max_dist_m: float = np.inf
) -> np.ndarray:
    """(N,) distance from each point of ``a`` to its nearest point of ``b`` (m).

    Parameters
    ----------
    a : (N, 3) float64
    b : (M, 3) float64
    max_dist_m : float
        Distances beyond this come back as inf (faster on far points).

    Returns
    -------
    (N,) float64
    """
    from scipy.spatial import cKDTree

    if len(a) == 0 or len(b) == 0:
        return np.full(len(a), np.inf)
    d = cKDTree(b).query(a, distance_upper_bound=max_dist_m)[0]
    return np.asarray(d, float)


@dataclass(frozen=True, slots=True)
class StemSlice:
    """One horizontal slice through both scans at a height above the tree base.

    Attributes
    ----------
    height_m : float
        Height of the slice's middle above the base.
    target_xy, source_xy : (N, 2), (M, 2) float64
        Slice points near the stem (source already moved into the target frame).
    target_circle, source_circle : StemCircle or None
        The fitted stem circle of each scan, None when none was found.
    """

    height_m: float
    target_xy: np.ndarray
    source_xy: np.ndarray
    target_circle: StemCircle | None
    source_circle: StemCircle | None

    @property
    def offset_m(self) -> float:
        """Distance between the two circle centres (m); NaN without both circles."""
        if self.target_circle is None or self.source_circle is None:
            return float("nan")
        return float(
            np.hypot(
                *(
                    np.subtract(
                        self.source_circle.centre_xy, self.target_circle.centre_xy
                    )
                )
            )
        )


def tree_base(xyz: np.ndarray) -> float:
    """Return the height of the tree base: the 0.5th percentile of z.

    A few stray points below the ground do not move it.
    """
    return float(np.percentile(xyz[:, 2], 0.5)) if len(xyz) else 0.0


def stem_slices(
    target_xyz: np.ndarray,
    moved_source_xyz: np.ndarray,
    heights_m: tuple[float, ...] = DEFAULT_HEIGHTS_M,
    thickness_m: float = DEFAULT_THICKNESS_M,
    params: MeasureParams | None = None,
) -> list[StemSlice]:
    """Slice both scans at heights above the target's base and fit each stem circle.

    Parameters
    ----------
    target_xyz : (N, 3) float64
    moved_source_xyz : (M, 3) float64
        Source points under the transform being judged (target frame).
    heights_m : tuple of float
        Heights above the base (m).
    thickness_m : float
        Slice thickness (m).
    params : MeasureParams or None
        Circle fit settings (default MeasureParams()).

    Returns
    -------
    list of StemSlice
    """
    params = params or MeasureParams()
    base = tree_base(target_xyz)
    low = target_xyz[target_xyz[:, 2] < base + 1.0]
    axis = np.median(low[:, :2], axis=0) if len(low) else np.zeros(2)
    out = []
    for h in heights_m:
        z0, z1 = base + h - thickness_m / 2, base + h + thickness_m / 2
        parts = []
        for xyz in (target_xyz, moved_source_xyz):
            sl = xyz[(xyz[:, 2] >= z0) & (xyz[:, 2] < z1), :2]
            sl = sl[np.hypot(*(sl - axis).T) < _STEM_RADIUS_M] if len(sl) else sl
            parts.append(np.asarray(sl, float))
        circles = [fit_stem_circle(p, params) for p in parts]
        out.append(StemSlice(float(h), parts[0], parts[1], circles[0], circles[1]))
    return out
