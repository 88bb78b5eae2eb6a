"""Find a tree cloud's stem at breast height, the ground under it, and its circle.

A scan clipped around a tree in the field holds ground, shrubs and neighbours: its
lowest point is the ground downhill at the edge of the clip, and a neighbour's stem may
cross the breast-height slice. So the stem is found first: of the stems in the slice,
the one nearest the middle of the cloud's footprint, where a clip around the tree puts
it (circles with a small share of the best one's support, twigs and shrubs, do not
count). A stem is solid, so a circle with more points well inside it than on it runs
through branches around something (often the stem) and is no stem. The base is then
the lowest points at that stem, followed down a leaning stem, and breast height is
taken from there.

The diameter comes from circles fitted to five slices 10 cm apart around breast
height: of the circles, the one most others agree with (centre and size), and the
median diameter of those that agree. One slice through a branch, a bump of bark or a
short arc does not decide it; when fewer than three slices agree, the DBH is doubtful.
When fewer than three slices have a circle at all (a stem behind its branches shows
little bark), one circle on the bark of the five slices together gives the DBH.
A circle thicker than the tree's height allows (height over diameter under 15) is no
stem: a conifer's branch whorls can look like bark to the surface test.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import TYPE_CHECKING

import numpy as np

from amrst.measure.stem import StemCircle, fit_stem_circle, stem_surface

if TYPE_CHECKING:
    from amrst.measure import MeasureParams
    from amrst.progress import Reporter

# A point with fewer than this many others within _ISOLATION_M is a stray.
_ISOLATION_M = 0.3
_MIN_NEIGHBOURS = 2
# Height over stem diameter of real trees stays above this (open-grown broadleaves and
# palms about 30-40, forest conifers 60-100).
_MIN_SLENDERNESS = 15.0
# Stems told apart in one slice at most, and the gap between two (closer: a buttress,
# a branch stub or a bump of the same stem). A stem has at least this share of the
# best-supported circle's points times arc.
_MAX_STEMS = 3
_STEM_GAP_M = 0.3
_MIN_SUPPORT = 0.25
# A stem is solid: a circle with more of the slice's points over _INSIDE_M inside it
# than on it is no stem. Circles tried per slice at most.
_INSIDE_M = 0.05
_MAX_TRIES = 6
# No stem at breast height above the cloud's lowest point (a slope, a shrub): look
# this much higher, this many times.
_SEARCH_STEP_M = 0.5
_SEARCH_STEPS = 4
# The base: the lowest points with company within this of the stem's circle, followed
# down in steps of _BASE_STEP_M; the stem is measured again from it until the base
# moves less than _BASE_TOL_M.
_BASE_MARGIN_M = 0.1
_BASE_STEP_M = 0.25
_BASE_LOWEST = 50
_BASE_ROUNDS = 3
_BASE_TOL_M = 0.02
# Slices are searched within this many stem radii plus this of the stem's centre.
_NEAR_FACTOR = 1.5
_NEAR_MARGIN_M = 0.2
# The slices around breast height, and when two of their circles agree: diameters
# within the larger of _AGREE_M and _AGREE_FRACTION, centres within the larger of
# _CENTRE_M and _CENTRE_FRACTION of the radius.
_SLICE_OFFSETS_M = (-0.2, -0.1, 0.0, 0.1, 0.2)
_AGREE_M = 0.02
_AGREE_FRACTION = 0.1
_CENTRE_M = 0.03
_CENTRE_FRACTION = 0.5
_MIN_AGREEING = 3


@dataclass(frozen=True, slots=True)
class BreastHeightStem:
    """The stem circle a DBH is read from, the base under it, and what is wrong.

    ``stem`` is None when no stem was found (``note`` says why); ``doubt`` says why a
    found stem circle should not be trusted, or is "".
    """

    stem: StemCircle | None
    base_z: float
    note: str = ""
    doubt: str = ""


def with_company(
    xyz: np.ndarray,
    weight: np.ndarray,
    candidates: np.ndarray,
    others: int = _MIN_NEIGHBOURS,
) -> np.ndarray:
    """Of the candidate rows, the ones with neighbours (not isolated strays).

    ``xyz`` holds distinct points; ``weight`` how many input points each stands for,
    so a point repeated many times still counts as its copies. A candidate needs at
    least ``others`` other points within ``_ISOLATION_M``.
    """
    from scipy.spatial import cKDTree

    # Only points near the candidates' heights can be their neighbours.
    z = xyz[candidates, 2]
    band = (xyz[:, 2] >= z.min() - _ISOLATION_M) & (xyz[:, 2] <= z.max() + _ISOLATION_M)
    near, near_weight = xyz[band], weight[band]
    tree = cKDTree(near)
    counts = np.asarray(
        tree.query_ball_point(xyz[candidates], _ISOLATION_M, return_length=True)
    )
    # Few distinct neighbours: count their copies too (short lists, cheap).
    few = np.flatnonzero(counts <= others)
    if len(few):
        lists = tree.query_ball_point(xyz[candidates[few]], _ISOLATION_M)
        counts[few] = [int(near_weight[ix].sum()) for ix in lists]
    return candidates[counts > others]  # counts include the point itself


def _slice_stems(
    xyz: np.ndarray,
    bark: np.ndarray,
    z_centre: float,
    params: MeasureParams,
    near: StemCircle | None = None,
) -> list[StemCircle]:
    """Stem circles on the bark points of the slice at ``z_centre``, best first.

    With ``near``, only the one circle among the points around that stem.
    """
    pick = bark & (np.abs(xyz[:, 2] - z_centre) <= params.slice_m / 2)
    if near is not None:
        reach = _NEAR_FACTOR * near.radius_m + _NEAR_MARGIN_M
        pick &= np.hypot(*(xyz[:, :2] - near.centre_xy).T) <= reach
    xy = xyz[pick, :2]
    every = xyz[np.abs(xyz[:, 2] - z_centre) <= params.slice_m / 2, :2]
    found: list[StemCircle] = []
    for _ in range(_MAX_TRIES):
        circle = fit_stem_circle(xy, params)
        if circle is None:
            break
        gap = np.hypot(*(xy - circle.centre_xy).T) - circle.radius_m
        if _hollow(every, circle):
            # Only its own points go: the stem it ran around may be inside.
            xy = xy[np.abs(gap) > params.inlier_m]
            continue
        found.append(circle)
        if len(found) == (1 if near is not None else _MAX_STEMS):
            break
        xy = xy[gap > _STEM_GAP_M]
    return found


def _hollow(xy: np.ndarray, circle: StemCircle) -> bool:
    """Tell whether more of a slice's points lie well inside the circle than on it.

    A stem is solid: a scan sees nothing inside it.
    """
    inside = np.hypot(*(xy - circle.centre_xy).T) < circle.radius_m - _INSIDE_M
    return bool(inside.sum() > circle.n_points)


def _locate(
    xyz: np.ndarray, base: float, params: MeasureParams
) -> tuple[StemCircle | None, float]:
    """Find the tree's stem in the lowest slice from breast height up that has one.

    Returns the circle and the height of its slice's middle.
    """
    mid = np.percentile(xyz[:, :2], [1, 99], axis=0).mean(axis=0)
    half = params.slice_m / 2
    for k in range(_SEARCH_STEPS):
        z = base + params.breast_height_m + k * _SEARCH_STEP_M
        stems = _slice_stems(xyz, stem_surface(xyz, z, half), z, params)
        if not stems:
            continue
        support = [c.n_points * c.arc_deg for c in stems]
        strong = [
            c
            for c, s in zip(stems, support, strict=True)
            if s >= _MIN_SUPPORT * max(support)
        ]
        return min(
            strong, key=lambda c: float(np.hypot(*np.subtract(c.centre_xy, mid)))
        ), z
    return None, base + params.breast_height_m


def _local_base(
    xyz: np.ndarray, weight: np.ndarray, stem: StemCircle, below: float
) -> float | None:
    """Return the lowest points with company at the stem below ``below`` (or None).

    The stem is followed down in steps: a leaning stem leaves a vertical cylinder,
    and the lowest points left inside would be stem, metres above the ground. Each
    step's search circle moves as the mean of its points moved from the step above
    (the mean of a half-seen stem lies off its centre, but by the same offset at
    every height).
    """
    centre = np.asarray(stem.centre_xy, dtype=np.float64)
    reach = stem.radius_m + _BASE_MARGIN_M
    below_idx = np.flatnonzero(xyz[:, 2] < below)
    pts = xyz[below_idx]
    found = []
    top, last = below, None
    while True:
        band = (pts[:, 2] < top) & (pts[:, 2] >= top - _BASE_STEP_M)
        band &= np.hypot(*(pts[:, :2] - centre).T) <= reach
        if not band.any():
            break
        mean = pts[band, :2].mean(axis=0)
        if last is not None:
            centre = centre + (mean - last)
        found.append(np.flatnonzero(band))
        top, last = top - _BASE_STEP_M, mean
    if not found:
        return None
    idx = below_idx[np.concatenate(found)]
    if len(idx) > _BASE_LOWEST:
        idx = idx[np.argpartition(xyz[idx, 2], _BASE_LOWEST - 1)[:_BASE_LOWEST]]
    kept = with_company(xyz, weight, idx)
    return float(xyz[kept, 2].min()) if len(kept) else None


def _agree(a: StemCircle, b: StemCircle) -> bool:
    """Tell whether two slices' circles are the same stem (centre and size)."""
    r = min(a.radius_m, b.radius_m)
    size = abs(a.radius_m - b.radius_m) * 2 <= max(_AGREE_M, _AGREE_FRACTION * 2 * r)
    offset = float(np.hypot(*np.subtract(a.centre_xy, b.centre_xy)))
    return size and offset <= max(_CENTRE_M, _CENTRE_FRACTION * r)


def consensus(circles: list[StemCircle]) -> tuple[StemCircle, int]:
    """Pick the circle most others agree with in centre and size (ties: widest arc).

    Parameters
    ----------
    circles : list of StemCircle
        One stem's circles at several heights (at least one).

    Returns
    -------
    StemCircle
        That circle, at the median radius of the circles that agree with it.
    int
        How many agree, itself included.
    """
    groups = [[b for b in circles if _agree(a, b)] for a in circles]
    best = max(range(len(circles)), key=lambda i: (len(groups[i]), circles[i].arc_deg))
    radius = float(np.median([c.radius_m for c in groups[best]]))
    return replace(circles[best], radius_m=radius), len(groups[best])


def circles_around(
    xyz: np.ndarray,
    stem: StemCircle,
    z: float,
    params: MeasureParams,
    *,
    stacked: bool = False,
) -> list[StemCircle]:
    """Fit a stem's circles in five slices 10 cm apart around height ``z``.

    Parameters
    ----------
    xyz : (N, 3) float64
        Points around the stem (others are left out).
    stem : StemCircle
        Roughly where the stem is: each slice is searched within 1.5 of its radii
        plus 0.2 m of its centre.
    z : float
        Height of the middle slice.
    params : MeasureParams
        The slices' thickness and the circle fit.
    stacked : bool
        One circle on the bark points of the five slices together instead.

    Returns
    -------
    list of StemCircle
        One per slice that has a stem circle, lowest first.
    """
    # Bark is told on the points around the stem only (not the neighbours' stems).
    half = max(abs(o) for o in _SLICE_OFFSETS_M) + params.slice_m / 2
    around = _NEAR_FACTOR * stem.radius_m + _NEAR_MARGIN_M + _NEAR_MARGIN_M
    near = xyz[
        (np.abs(xyz[:, 2] - z) <= half + _NEAR_MARGIN_M)
        & (np.hypot(*(xyz[:, :2] - stem.centre_xy).T) <= around)
    ]
    bark = stem_surface(near, z, half)
    if stacked:
        return _slice_stems(near, bark, z, replace(params, slice_m=2 * half), stem)
    out = []
    for dz in _SLICE_OFFSETS_M:
        out += _slice_stems(near, bark, z + dz, params, stem)
    return out


def _no_stem(xyz: np.ndarray, base: float, params: MeasureParams) -> str:
    """Why no stem was found, with the counts of the breast-height slice."""
    z = base + params.breast_height_m
    half = params.slice_m / 2
    in_slice = np.abs(xyz[:, 2] - z) <= half
    bark = in_slice & stem_surface(xyz, z, half)
    return (
        f"no stem circle at {params.breast_height_m} m above the base "
        f"({int(in_slice.sum())} points in the slice, {int(bark.sum())} on bark-like "
        "surfaces): the stem may be hidden by branches, or the cloud holds ground or "
        "several trees"
    )


def _too_thick(circle: StemCircle, height: float, params: MeasureParams) -> str:
    return (
        f"the only circle at {params.breast_height_m} m above the base "
        f"({200 * circle.radius_m:.0f} cm across) is too thick for a "
        f"{height:.1f} m tree (height/diameter under {_MIN_SLENDERNESS:.0f}): "
        "it follows branches, not the stem, which is hidden"
    )


def breast_height_stem(
    xyz: np.ndarray,
    weight: np.ndarray,
    base: float,
    top: float,
    params: MeasureParams,
    reporter: Reporter,
) -> BreastHeightStem:
    """Find the tree's stem, the base under it, and its circle at breast height.

    Parameters
    ----------
    xyz : (N, 3) float64
        Distinct points of one tree cloud (see :func:`amrst.measure.distinct_points`).
    weight : (N,) int64
        How many input points each stands for.
    base, top : float
        Heights of the cloud's lowest and highest points with company.
    params : MeasureParams
    reporter : Reporter
        Checked for Cancel between the slices.

    Returns
    -------
    BreastHeightStem
        The base is ``base`` when no stem was found.
    """
    # Circles thicker than the tree's height allows are not candidates at all: a
    # wide circle through branches would hide the stem inside it.
    limit = min(params.max_radius_m, (top - base) / (2 * _MIN_SLENDERNESS))
    capped = replace(params, max_radius_m=max(limit, 0.0))
    stem, z = _locate(xyz, base, capped)
    reporter.check_cancelled()
    if stem is None:
        thick, _z = _locate(xyz, base, params)
        if thick is not None:
            return BreastHeightStem(None, base, _too_thick(thick, top - base, params))
        return BreastHeightStem(None, base, _no_stem(xyz, base, params))
    circles: list[StemCircle] = []
    for _ in range(_BASE_ROUNDS):
        local = _local_base(xyz, weight, stem, z)
        moved = local is not None and abs(local - base) >= _BASE_TOL_M
        base = base if local is None else local
        z = base + params.breast_height_m
        found = circles_around(xyz, stem, z, capped)
        reporter.check_cancelled()
        if not found:
            break
        circles = found
        stem = consensus(circles)[0]
        if not moved:
            break
    if not circles:
        return BreastHeightStem(None, base, _no_stem(xyz, base, params))
    stem, agreeing = consensus(circles)
    if len(circles) < _MIN_AGREEING:
        # Little bark around breast height (a stem behind its branches): one circle
        # on the bark of the five slices together, when it is the same stem.
        stacked = circles_around(xyz, stem, z, capped, stacked=True)
        stem = next((c for c in stacked if _agree(c, stem)), stem)
    if top - base < _MIN_SLENDERNESS * 2 * stem.radius_m:
        return BreastHeightStem(None, base, _too_thick(stem, top - base, params))
    return BreastHeightStem(stem, base, "", _doubt(circles, agreeing, params))


def _doubt(circles: list[StemCircle], agreeing: int, params: MeasureParams) -> str:
    """Why the slices' circles do not bear the DBH out, or ""."""
    if agreeing >= _MIN_AGREEING:
        return ""
    across = [200 * c.radius_m for c in circles]
    low = params.breast_height_m + min(_SLICE_OFFSETS_M)
    high = params.breast_height_m + max(_SLICE_OFFSETS_M)
    slices = f"{len(_SLICE_OFFSETS_M)} slices from {low:g} to {high:g} m"
    if len(circles) < _MIN_AGREEING:
        return (
            f"only {len(circles)} of the {slices} show a stem circle: the stem is "
            "mostly hidden"
        )
    return (
        f"only {agreeing} of the {slices} fit the same stem circle (circles "
        f"{min(across):.0f} to {max(across):.0f} cm across)"
    )
