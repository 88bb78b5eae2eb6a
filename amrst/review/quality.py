"""What the technician judges a registration by: distances and stem slices.

Cloud-to-cloud distances both ways (CloudCompare's check) and horizontal stem slices
with the circle of each scan and the offset between the centres (the forester's own
check: stems must overlap in every slice). Used by the app's quality views and by the
registration report. No Qt, no pyvista.

Each scan sees about half of a stem, and a circle fitted to half an arc trades its
radius against its centre: on an irregular stem two correct scans' circles lie
centimetres apart. So the radius comes from one circle fitted to both scans' points,
and each scan's centre is fitted at that radius.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from amrst.measure import MeasureParams, StemCircle, fit_stem_circle
from amrst.measure.stem import arc_deg, centre_at_radius

DEFAULT_HEIGHTS_M = (0.3, 1.3, 3.0)
DEFAULT_THICKNESS_M = 0.1
_STEM_RADIUS_M = 1.5  # slice points farther than this from the stem axis are crown
# A slice's circle is trusted to judge a centre offset only when it rests on this many
# points, this share of the slice's points, over this arc, and both scans' radii agree
# within the larger of these (a flared base or roots fit no single circle, and circles
# through a few root points lie far apart even when the pose is right).
MIN_SLICE_POINTS = 20
MIN_SLICE_SHARE = 0.4
MIN_SLICE_ARC_DEG = 90.0
#: Slice points this close to the common circle are its inliers (m).
_INLIER_BAND_M = 0.03


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
        Each scan's circle at the common radius, None when none was found.
    """

    height_m: float
    target_xy: np.ndarray
    source_xy: np.ndarray
    target_circle: StemCircle | None
    source_circle: StemCircle | None

    def problem(self) -> str:
        """Why the centre offset cannot be trusted, in plain words; "" when it can."""
        fits = (
            ("target", self.target_circle, len(self.target_xy)),
            ("source", self.source_circle, len(self.source_xy)),
        )
        missing = [name for name, c, _n in fits if c is None]
        if missing:
            return f"no stem circle in the {' and '.join(missing)} scan"
        for name, c, n in fits:
            assert c is not None
            share = c.n_points / max(n, 1)
            if (
                c.n_points < MIN_SLICE_POINTS
                or share < MIN_SLICE_SHARE
                or c.arc_deg < MIN_SLICE_ARC_DEG
            ):
                return (
                    f"fit unreliable: the {name} circle rests on {c.n_points} of "
                    f"{n} points ({share:.0%}) over {c.arc_deg:.0f}°, residual "
                    f"{c.rmse_m * 1000:.1f} mm"
                )
        return ""

    def caption(self) -> tuple[str, str]:
        """Two short lines: the height, then the offset or why it is not shown."""
        why = self.problem()
        return (
            f"{self.height_m:g} m above the base",
            why if why else f"centres {self.offset_m * 1000:.1f} mm apart",
        )

    def as_dict(self) -> dict[str, object]:
        """Height, the common diameter, the centre offset and ``status``."""
        tc = self.target_circle
        return {
            "height_m": self.height_m,
            "diameter_m": None if tc is None else 2 * tc.radius_m,
            "offset_m": self.offset_m,
            "status": self.problem() or "ok",
        }

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

    The radius is the one of a circle through both scans' slice points; each scan's
    centre is then fitted at that radius (see the module's note).

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
        common = fit_stem_circle(np.vstack(parts), params)
        circles = [
            None if common is None else circle_at_radius(p, common) for p in parts
        ]
        out.append(StemSlice(float(h), parts[0], parts[1], circles[0], circles[1]))
    return out


def circle_at_radius(xy: np.ndarray, start: StemCircle) -> StemCircle | None:
    """Fit the centre of a circle of ``start``'s radius to one scan's slice points.

    A soft-L1 fit of the centre on the points within 3 cm of ``start``; None when
    fewer than five lie there.
    """
    radius = start.radius_m
    c0 = np.asarray(start.centre_xy, float)
    near = (
        xy[np.abs(np.hypot(*(xy - c0).T) - radius) < _INLIER_BAND_M] if len(xy) else xy
    )
    if len(near) < 5:
        return None

    centre = centre_at_radius(near, c0, radius, 0.005)
    r = np.hypot(*(near - centre).T) - radius
    inliers = near[np.abs(r) < _INLIER_BAND_M / 2]
    if not len(inliers):
        return None
    return StemCircle(
        centre_xy=(float(centre[0]), float(centre[1])),
        radius_m=float(radius),
        rmse_m=float(np.sqrt(np.mean(r[np.abs(r) < _INLIER_BAND_M / 2] ** 2))),
        n_points=len(inliers),
        arc_deg=arc_deg(inliers, centre),
    )
