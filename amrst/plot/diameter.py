"""The DBH of a plot tree: circles in slices from 1.0 to 1.6 m, one taper line.

One circle at breast height goes wrong on whatever crosses that slice: a branch, a
bump of the bark, a fork. Each 10 cm slice gets its own circle (all the slice's points
around the stem line, :func:`amrst.measure.fit_stem_circle`). The circles that one
straight line of diameter over height holds (within ``AGREE_M`` or ``AGREE_SHARE`` of
the diameter, its slope a plausible taper) are the stem's; slices near breast height
count a little more, so a tie goes to them. The DBH is the median of those circles:
the slices are centred on breast height, and a median is not pulled up by a flared
foot or a bump the way a least-squares line's value there is.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from amrst.measure import MeasureParams, fit_stem_circle

if TYPE_CHECKING:
    from amrst.measure.stem import StemCircle

#: Centres of the slices above the ground (m), and their half thickness.
SLICE_HEIGHTS_M = (1.0, 1.1, 1.2, 1.3, 1.4, 1.5, 1.6)
SLICE_HALF_M = 0.05
BREAST_HEIGHT_M = 1.3
#: Slopes of the taper line tried (diameter change per metre up, a share of the
#: diameter): a stem narrows upwards, by a quarter of its diameter per metre at most.
TAPER_SLOPES = np.linspace(-0.25, 0.05, 7)
#: A circle agrees with the line within the larger of these.
AGREE_M = 0.01
AGREE_SHARE = 0.06
#: The slices' points lie within the stem radius plus this of the stem line (m).
WINDOW_MARGIN_M = 0.15


@dataclass(frozen=True, slots=True)
class TaperFit:
    """The stem's diameter over several slices.

    ``dbh_m`` and ``per_m`` (change per metre up) make the taper line; ``circles``
    are the slice circles on it, (height above the ground, circle), of ``fitted``;
    ``circle`` is the one nearest breast height, ``slice_xy`` its slice's points.
    """

    dbh_m: float
    per_m: float
    circles: tuple[tuple[float, StemCircle], ...]
    fitted: int
    circle: StemCircle
    slice_xy: np.ndarray  # (M, 2)

    def at(self, height_m: float) -> float:
        """Return the line's diameter ``height_m`` above the ground."""
        return self.dbh_m + self.per_m * (height_m - BREAST_HEIGHT_M)

    def agrees(self, at: float, diameter_m: float) -> bool:
        """Tell whether a circle of ``diameter_m`` at height ``at`` lies on the line."""
        line = self.at(at)
        return abs(diameter_m - line) <= max(AGREE_M, AGREE_SHARE * line)


def taper_dbh(
    xyz: np.ndarray,
    h: np.ndarray,
    axis: tuple[np.ndarray, np.ndarray],
    radius_m: float,
    inlier_m: float,
) -> TaperFit | None:
    """Fit the stem's diameter at breast height over slices 1.0-1.6 m.

    Parameters
    ----------
    xyz : (N, 3) float64
        Points around the stem (more than the window is fine).
    h : (N,) float64
        Their heights above the ground (m).
    axis : ((2,) float64, (2,) float64)
        The stem line: position at the ground and horizontal shift per metre up.
    radius_m : float
        A first guess of the stem radius (the window's size).
    inlier_m : float
        Circle inlier band (m).

    Returns
    -------
    TaperFit or None
        None when no slice has a circle.
    """
    mp = MeasureParams(inlier_m=inlier_m, max_radius_m=1.0)
    reach = radius_m + WINDOW_MARGIN_M
    fits: list[tuple[float, StemCircle, np.ndarray]] = []
    for at in SLICE_HEIGHTS_M:
        centre = axis[0] + axis[1] * at
        xy = xyz[
            (np.abs(h - at) <= SLICE_HALF_M)
            & (np.hypot(xyz[:, 0] - centre[0], xyz[:, 1] - centre[1]) <= reach),
            :2,
        ]
        circle = fit_stem_circle(xy, mp)
        if circle is not None:
            fits.append((at, circle, xy))
    if not fits:
        return None
    heights = np.array([f[0] for f in fits])
    d = np.array([2 * f[1].radius_m for f in fits])
    agree = _taper_inliers(heights, d)
    z = heights[agree] - BREAST_HEIGHT_M
    dbh, per_m = np.median(d[agree]), 0.0
    if agree.sum() >= 3 and np.ptp(z) >= 0.3:
        A = np.column_stack([np.ones(len(z)), z])
        per_m = np.linalg.lstsq(A, d[agree], rcond=None)[0][1]
    on = np.flatnonzero(agree)
    best = on[np.argmin(np.abs(z))]
    return TaperFit(
        float(dbh),
        float(per_m),
        tuple((fits[i][0], fits[i][1]) for i in on),
        len(fits),
        fits[best][1],
        fits[best][2],
    )


def _taper_inliers(at: np.ndarray, d: np.ndarray) -> np.ndarray:
    """Mark the circles on the taper line most of them agree with."""
    best = np.zeros(len(d), dtype=bool)
    best_score = -np.inf
    for i in range(len(d)):
        for slope in TAPER_SLOPES:
            line = d[i] * (1.0 + slope * (at - at[i]))
            on = np.abs(d - line) <= np.maximum(AGREE_M, AGREE_SHARE * line)
            score = on.sum() - 0.01 * np.abs(at[on] - BREAST_HEIGHT_M).sum()
            if score > best_score:
                best, best_score = on, score
    return best
