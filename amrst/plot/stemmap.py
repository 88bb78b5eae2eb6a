"""The stem map of a plot: every stem with its base, DBH, height, lean and quality.

One function, :func:`map_stems`, serves a single scan (the key points of the plot
registration) and the merged plot (the inventory):

1. the ground surface (``stages/ground.py``) and each point's height above it;
2. stems: clusters of a slice above the ground that cross it and are narrow enough
   (``stages/stems.py``);
3. per stem, circles on bark-like points (``measure/stem.py``) in thin slices at a few
   heights: the one at breast height gives the DBH, all of them the lean, and the
   lowest (0.6 m up) the base, or the stem line where it meets the ground.

The inventory (``trees=True``) goes on:

4. a stem with too few circles looked at again in thicker slices and higher up
   (:func:`_look_again`); stems hidden at their foot: bark seen higher up, away from
   the stems found;
5. every point above the ground goes to the stem it reaches at the least path cost
   (``plot/crowns.py``), from the stem followed up above its circles
   (:func:`_trace_stem`), and the tree's highest point gives its height;
6. the DBH is the taper line of circles in slices 1.0-1.6 m (``plot/diameter.py``),
   and the stem line is fitted again to the circles on it;
7. a tree whose foot shows no circle and is wrapped in its own branches (a spruce)
   stands where its branches point (:func:`branch_axis`); a slice cluster that
   such branches wrap is a tree too, even with no circle at all.

The DBH quality follows 3DFin's section checks: the arc of the stem the circle's
inliers cover, the fit residual, the share of slice points off the circle, and the
agreement of the circle with the stem's other circles.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import TYPE_CHECKING

import numpy as np

from amrst.measure import MeasureParams, fit_stem_circle
from amrst.measure.stem import stem_surface
from amrst.plot.crowns import assign_crowns, tree_top
from amrst.plot.diameter import BREAST_HEIGHT_M, WINDOW_MARGIN_M, taper_dbh
from amrst.stages.ground import GroundFit, fit_ground
from amrst.stages.scene import SceneParams
from amrst.stages.stems import crosses_slice, find_stems
from amrst.stages.voxels import voxel_sample

if TYPE_CHECKING:
    from collections.abc import Mapping

    from amrst.measure.stem import StemCircle
    from amrst.progress import Reporter

#: A DBH circle's outlier share counts the slice points within OUTLIER_NEAR_M of it
#: (m); those over OUTLIER_OFF_M off it are its outliers.
OUTLIER_NEAR_M = 0.1
OUTLIER_OFF_M = 0.02
#: Heights above the ground of the slices the stem line is fitted to (m).
LINE_HEIGHTS_M = (0.6, 1.0, 1.3, 1.7, 2.2)
#: The second look at a stem with too few circles (:func:`_look_again`) goes up to
#: 2.6 m.
AGAIN_HEIGHTS_M = (*LINE_HEIGHTS_M, 2.6)
#: The circle at the foot is the tree's position (``_foot_xy``) unless it is this many
#: times wider than the taper line there.
FOOT_WIDER = 1.5
#: Points around a stem the slices take (m beyond the stem cluster's extent).
STEM_MARGIN_M = 0.15
#: A tree the technician gives: its stem is the points this high above the ground
#: (m) within this reach of their point.
GIVEN_LOW_M, GIVEN_HIGH_M = 0.5, 2.0
GIVEN_REACH_M = 0.5
#: A given point with no point of the plot this near (m, across) is out of every
#: scan's sight: no tree is listed there (the ground would be guessed far off).
GIVEN_SEEN_M = 5.0
#: Branch lines (``branch_axis``): 3 cm voxels from 2 m up to 3/4 of the tree, the
#: line of each through its neighbours within 15 cm when they lie on one (share of
#: variance off the main axis under ``1 - AXIS_LINEAR``) and it runs level enough.
AXIS_VOXEL_M = 0.03
AXIS_LOW_M = 2.0
AXIS_HIGH_SHARE = 0.75
AXIS_RADIUS_M = 0.15
AXIS_LINEAR = 0.8
AXIS_LEVEL = 0.8  # horizontal part of the line's direction
#: Lines 0.25-2 m from the axis count; a line within ``AXIS_NEAR_M`` passes it.
AXIS_RANGE_M = (0.25, 2.0)
AXIS_NEAR_M = 0.1
#: A spruce's skirt: its own points this high above the ground (m) and this far from
#: the axis (m), counted in 12 directions around it.
SKIRT_HEIGHT_M = (0.5, 2.5)
SKIRT_REACH_M = (0.3, 1.5)
#: A wrapped stem (:func:`_add_wrapped_stems`): the branches within this reach (m)
#: of a slice cluster's centre say where its stem is, within half of it.
WRAP_REACH_M = 2.5
WRAPPED_WHY = "the stem is hidden in its branches"
#: Following a stem up (:func:`_trace_stem`), slab by slab of ``TRACE_STEP_M``: the
#: points within its radius plus ``TRACE_TOL_M`` of the axis, when at least
#: ``TRACE_MIN_POINTS`` and no fewer than those in the ``TRACE_RING_M`` ring around
#: them (a stem is narrow, a crown wide), are stem.
TRACE_STEP_M = 0.4
TRACE_TOL_M = 0.1
TRACE_MIN_POINTS = 5
TRACE_RING_M = 0.3
#: A neighbour's crown can hide a few metres of stem: the trace goes on that far.
TRACE_GAP_M = 3.0
#: The axis moves this share of the way to the stem points of each slab: the points
#: show one side of the stem, and a stem bends slowly.
TRACE_FOLLOW = 0.5
#: Points farther than this (m) across from the stem line are never its stem.
TRACE_DRIFT_M = 3.0


@dataclass(frozen=True, slots=True, kw_only=True)
class StemMapParams:
    """Settings of the stem map (a plot's trees found and measured)."""

    voxel_m: float = 0.01  # thinning of the input before anything else
    max_points: int = 4_000_000  # after thinning, an even stride beyond this
    ground_cell_m: float = 0.5
    ground_tol_m: float = 0.15
    ground_dist_m: float = 0.15  # points lower than this above the ground are ground
    max_slope_deg: float = 25.0
    min_ground_area_m2: float = 12.0
    dbh_low_m: float = 1.25  # the DBH slice, above the local ground
    dbh_high_m: float = 1.35
    circle_inlier_m: float = 0.01
    # DBH quality: ok needs the arc, the residual and the outlier share below. The arc
    # (360 deg less the widest gap between the circle's points) as 3DFin's default of
    # 9 of 16 sectors: a circle whose points leave half the stem or more unseen in one
    # piece is not held on both sides.
    ok_arc_deg: float = 202.5
    # A stem wider than wide_stem_m seen over less than wide_arc_deg gets no DBH: a
    # wide stem's section is seldom round, and a short arc of it does not fix the circle.
    # For the same reason its DBH is ok only from wide_ok_arc_deg, two thirds of it.
    wide_stem_m: float = 0.5
    wide_arc_deg: float = 150.0
    wide_ok_arc_deg: float = 240.0
    ok_rmse_m: float = 0.006
    ok_outlier_share: float = 0.3
    # Height flags: fewer points than min_top_points in the top metre of the tree is
    # top not seen (hidden or out of range; it wins over lean, as the worse); a
    # stem leaning more than lean_flag_deg, or a top farther off the vertical over
    # the stem's foot than top_lean_flag_deg (a bent tree, or a top taken from a
    # neighbour's crown), is lean. So is a top farther than conifer_top_off_m across
    # from a conifer's branch axis (:func:`_on_branch_axis`): its whorls radiate from
    # an upright stem, and its top stands over it.
    lean_flag_deg: float = 8.0
    top_lean_flag_deg: float = 10.0
    conifer_top_off_m: float = 1.0
    min_top_points: int = 15
    min_circles: int = 1  # bark circles a stem shows among the slices
    min_height_m: float = 2.0  # a lower stem is a shrub
    # In the inventory, a stem with bark circles at fewer than ``bark_heights`` of the
    # slice heights is listed only when its tree is at least ``hidden_tree_m`` high: the
    # tip of a branch that droops to the ground shows no more stem than that.
    bark_heights: int = 2
    hidden_tree_m: float = 10.0
    # Stems inside wide slice clusters (bark_seeds).
    bark_link_m: float = 0.06
    bark_min_points: int = 30
    bark_min_rise_m: float = 0.6
    bark_max_width_m: float = 1.0
    # Two circles of one stem: radii within this share (and 5 mm) of each other; the
    # DBH circle is checked against the circles just below and above it.
    taper_tol: float = 0.15
    # In the inventory, a DBH needs this many slice circles on the taper line, and all
    # but taper_misfits of those fitted (else the slices show no one stem: a buttress,
    # a lobed stem, branches), and a bark circle (0.6-2.2 m) that agrees with it.
    taper_min_circles: int = 3
    taper_misfits: int = 2
    refit_circles: int = 4  # the stem line refitted leans on this many circles
    # Stems hidden at their foot (inventory only): bark seeds this high above the
    # ground, this far from every stem found; bases this close are one stem.
    hidden_low_m: float = 1.0
    hidden_high_m: float = 3.0
    hidden_gap_m: float = 1.0
    same_stem_m: float = 0.3
    # A tree with no circle at its foot stands where its branches point
    # (:func:`branch_axis`) when ``axis_support`` of them do and its own branches hang
    # around that point in ``skirt_sectors`` of 12 directions (``SKIRT_*``). A circle
    # at the foot wider than ``wide_foot_m`` counts as none (it may go round the
    # branches), and so do circles farther than ``scattered_line_m`` from their median
    # centre (through branches: a stem's lie on a line).
    skirt_sectors: int = 10
    axis_support: float = 0.25
    wide_foot_m: float = 0.8
    scattered_line_m: float = 0.4
    scene: SceneParams = field(default_factory=SceneParams)


@dataclass(frozen=True, slots=True)
class StemRecord:
    """One stem of a stem map (local frame of the cloud it was found in).

    ``base`` is where the stem line meets the ground; ``dbh_xy`` the centre of the
    breast-height circle. ``dbh_quality``: ``ok``, ``check`` or ``none`` (no circle:
    ``arc_deg``, ``rmse_m`` and ``outlier_share`` NaN, but the arc of a wide stem seen
    over too little), ``dbh_why`` says why it is not ok where known; ``lean_deg`` is
    NaN where no stem line was measured;
    ``height_flag``: ``ok``, ``lean`` (the stem, or the line from its foot to the
    tree's top), ``top not seen``, ``top out of range`` (``height_m`` NaN and
    ``height_seen_m`` how high the tree was seen) and ``top not checked`` (no
    scanner position known), both set by the inventory, or ``not measured``.
    """

    base: np.ndarray  # (3,)
    dbh_xy: np.ndarray  # (2,)
    dbh_m: float
    arc_deg: float
    rmse_m: float
    outlier_share: float
    dbh_quality: str
    height_m: float
    height_flag: str
    lean_deg: float
    crown_width_m: float
    n_points: int
    given: str | None = None  # the id the technician gave the tree it stands for
    dbh_why: str = ""  # why the DBH is check or none, "; "-separated
    height_seen_m: float = float("nan")  # top out of range: how high it was seen

    @property
    def seen_to_m(self) -> float:
        """Return how high above its base the tree was seen (m).

        Its height, or, where its top was out of range, ``height_seen_m``.
        """
        return self.height_m if np.isfinite(self.height_m) else self.height_seen_m

    @property
    def key_xyz(self) -> np.ndarray:
        """(3,) the stem's key point: its breast-height centre, where it stands.

        At breast height, not on the ground: a pose levelled by turning about these
        points keeps the circles where the stems matched them (a 2° tilt about the
        ground would move them 4.5 cm).
        """
        return np.asarray(np.r_[self.dbh_xy, self.base[2] + BREAST_HEIGHT_M])


@dataclass(frozen=True, slots=True)
class StemMap:
    """The stems of a cloud, the ground under them, and which stem owns each point.

    ``xyz`` are the working points (thinned input), ``index`` their rows in the
    input (None: not known); ``owner[i]`` is the stem of ``xyz[i]`` (-1: ground,
    shrub or nothing).
    """

    stems: tuple[StemRecord, ...]
    ground: GroundFit
    xyz: np.ndarray
    owner: np.ndarray
    index: np.ndarray | None = None

    def keys(self) -> np.ndarray:
        """(S, 3) key points of the stems."""
        return np.array([s.key_xyz for s in self.stems]).reshape(-1, 3)

    def dbh(self) -> np.ndarray:
        """(S,) DBH of the stems (NaN where none)."""
        return np.array([s.dbh_m for s in self.stems], dtype=float)


def plot_ground(xyz: np.ndarray, params: StemMapParams) -> GroundFit:
    """Fit the ground under a plot cloud, as the stem map takes it.

    A plot scan reaches tens of metres (``fit_ground``'s ``wide``): lone stray points
    below the ground, one a cell, would outnumber the ground's cells, and no ground
    that wide is a plane.
    """
    return fit_ground(
        xyz,
        cell_m=params.ground_cell_m,
        tol_m=params.ground_tol_m,
        max_slope_deg=params.max_slope_deg,
        min_area_m2=params.min_ground_area_m2,
        iterations=300,
        seed=params.scene.seed,
        wide=True,
    )


#: The ways a scan may stand other than z up: each turn takes its points z up.
_TURNS = {
    "upside down": np.diag([1.0, -1.0, -1.0]),
    "with its y axis up": np.array([[1.0, 0, 0], [0, 0, -1], [0, 1, 0]]),
    "with its y axis down": np.array([[1.0, 0, 0], [0, 0, 1], [0, -1, 0]]),
    "with its x axis up": np.array([[0.0, 0, -1], [0, 1, 0], [1, 0, 0]]),
    "with its x axis down": np.array([[0.0, 0, 1], [0, 1, 0], [-1, 0, 0]]),
}


def which_way_up(stem_map: StemMap, params: StemMapParams | None = None) -> str:
    """Say how a scan seems to stand when a turn puts far more ground under it.

    A way holds the area of the ground it finds, unless a twentieth of the points
    hang more than half a metre below that ground (a scan upside down shows its
    ground on top of its trees, and the bare ground between them). "" when z up holds
    the most (or no way holds ``min_ground_area_m2``); else one of ``_TURNS``, e.g.
    "with its y axis up" (a common export slip). Each turn fits a ground again: for
    a scan that failed to register.
    """
    params = params or StemMapParams()

    def ground_area(xyz: np.ndarray) -> float:
        ground = plot_ground(xyz, params)
        if not ground.found or np.mean(ground.height(xyz) < -0.5) > 0.05:
            return 0.0
        return ground.area_m2

    upright = ground_area(stem_map.xyz)
    areas = {name: ground_area(stem_map.xyz @ R.T) for name, R in _TURNS.items()}
    best = max(areas, key=areas.__getitem__)
    enough = max(2.0 * upright, params.min_ground_area_m2)
    return best if areas[best] >= enough else ""


def working_index(xyz: np.ndarray, params: StemMapParams) -> np.ndarray:
    """Rows of ``xyz`` the stem map works on: thinned, at most ``max_points``."""
    index = np.arange(len(xyz))
    if params.voxel_m > 0 and len(xyz):
        index = np.asarray(voxel_sample(np.asarray(xyz, float), params.voxel_m))
    if len(index) > params.max_points:
        index = index[:: int(np.ceil(len(index) / params.max_points))]
    return index


def map_stems(
    xyz: np.ndarray,
    params: StemMapParams | None = None,
    reporter: Reporter | None = None,
    *,
    trees: bool = True,
    given: Mapping[str, tuple[float, float]] | None = None,
) -> StemMap:
    """Find and measure every stem of a plot cloud.

    Parameters
    ----------
    xyz : (N, 3) float64
        One scan or several merged, z up (m).
    params : StemMapParams or None
    reporter : Reporter or None
        Checked for Cancel between the stems.
    trees : bool
        The inventory: also find stems hidden at their foot, give every point above
        the ground to its stem, measure each tree's height and crown, and the DBH
        over several slices. Without it (the key points of a registration) the stems
        carry NaN heights, no point is owned, and a stem is kept on its bark circles
        alone.
    given : mapping of tree id to (x, y), or None
        With ``trees``: where the technician says a tree stands. Each point gives a
        stem: the one found within ``same_stem_m`` (a tree found, untagged, when the
        inventory keeps it), or one measured there (:func:`_add_given_stems`); the
        stem is tagged ``given`` with the point's id unless it is a tree found.

    Returns
    -------
    StemMap
        No stems when the cloud has no ground (a plot always shows one).
    """
    params = params or StemMapParams()
    index = working_index(xyz, params)
    pts = np.asarray(xyz, dtype=float)[index]
    say = reporter.progress if reporter is not None else lambda _f, _m="": None
    say(0.05, f"ground under {len(pts):,} points")
    ground = plot_ground(pts, params)
    owner = np.full(len(pts), -1, dtype=np.int64)
    if not ground.found:
        return StemMap((), ground, pts, owner, index)
    h = ground.height(pts)
    above = np.flatnonzero(h >= params.ground_dist_m)
    found, slice_lab, slice_idx = find_stems(pts, h, above, params.scene)
    seeds = [slice_idx[slice_lab == k] for k in range(len(found))]
    seeds += bark_seeds(pts, h, slice_idx[slice_lab < 0], params)
    given = given or {}
    if not seeds and not (trees and given):
        return StemMap((), ground, pts, owner, index)
    say(0.3, f"measuring {len(seeds)} stem candidates")
    fits: list[_StemFit | None] = []
    for seed in seeds:
        if reporter is not None:
            reporter.check_cancelled()
        fits.append(_measure_stem(pts, h, ground, seed, params))
    if trees:
        _look_again(pts, h, ground, seeds, fits, params)
        say(0.5, "stems hidden at their foot, crowns")
        _add_hidden_stems(pts, h, ground, seeds, fits, params)
        _add_wrapped_stems(pts, h, ground, slice_idx, seeds, fits, params=params)
        _merge_same_stems(seeds, fits, params)
        roles = _add_given_stems(pts, h, ground, seeds, fits, given, params=params)
        # Paths through a 5 cm graph: crowns go to the stem they hang from.
        # Its stem followed up joins each stem's seeds, at the cost of climbing it
        # from the slice: a stem hidden for a metre keeps its top and crown.
        by_h = above[np.argsort(h[above], kind="stable")]  # one sort for every trace
        xy_by_h, h_by_h = pts[by_h, :2], h[by_h]
        traced = []
        for fit in fits:
            if reporter is not None:
                reporter.check_cancelled()
            traced.append(
                by_h[_trace_stem(xy_by_h, h_by_h, fit)]
                if fit
                else np.zeros(0, np.int64)
            )
        del xy_by_h, h_by_h
        start = [
            np.r_[np.zeros(len(s)), np.maximum(h[t] - params.scene.stem_high_m, 0.0)]
            for s, t in zip(seeds, traced, strict=True)
        ]
        owner = assign_crowns(
            pts,
            h,
            above,
            [np.r_[s, t] for s, t in zip(seeds, traced, strict=True)],
            params.scene.crown_height_m,
            start,
        )
    stems: list[StemRecord] = []
    kept = np.full(len(seeds) + 1, -1, dtype=np.int64)  # cluster -> stem (-1: none)
    for k, fit in enumerate(fits):
        if reporter is not None:
            reporter.check_cancelled()
        if fit is None:
            continue
        stem = (
            _as_tree_or_given(
                fit, pts, h, ground, owner == k, params, role=roles.get(k, "")
            )
            if trees
            else fit.stem
        )
        if stem is not None:
            kept[k] = len(stems)
            stems.append(stem)
    return StemMap(tuple(stems), ground, pts, kept[owner], index)


def _trace_stem(xy: np.ndarray, h: np.ndarray, fit: _StemFit) -> np.ndarray:
    """Return the points of a stem above its circles, followed up slab by slab.

    ``xy`` and ``h`` are the points above the ground, sorted by height; the result
    indexes them. Each slab's axis goes on the stem line from the last slab of stem;
    the trace ends ``TRACE_GAP_M`` above it (``TRACE_*``).
    """
    if not fit.line:
        return np.zeros(0, np.int64)
    base_xy, slope, _ = _stem_line(fit.line, fit.stem.base[:2])
    radius = float(np.median(list(fit.radii.values())))
    last = max(at for at, _, _ in fit.line)
    axis = base_xy + slope * last
    inner_r = radius + TRACE_TOL_M
    took = [np.zeros(0, np.int64)]
    at = last
    while at - last <= TRACE_GAP_M:
        lo, hi = np.searchsorted(h, [at, at + TRACE_STEP_M])
        at += TRACE_STEP_M
        slab = np.arange(lo, hi)
        off = np.hypot(*(xy[slab] - base_xy - slope * h[slab, None]).T)
        slab = slab[off <= TRACE_DRIFT_M]
        centre = axis + slope * (at - TRACE_STEP_M / 2 - last)
        d = np.hypot(*(xy[slab] - centre).T)
        inner = slab[d <= inner_r]
        ring = np.sum((d > inner_r) & (d <= inner_r + TRACE_RING_M))
        if len(inner) < TRACE_MIN_POINTS or ring > len(inner):
            continue
        took.append(inner)
        axis = centre + TRACE_FOLLOW * (np.median(xy[inner], axis=0) - centre)
        last = at - TRACE_STEP_M / 2
    return np.concatenate(took)


def _look_again(
    pts: np.ndarray,
    h: np.ndarray,
    ground: GroundFit,
    seeds: list[np.ndarray],
    fits: list[_StemFit | None],
    params: StemMapParams,
) -> None:
    """Measure again the stems that show fewer than ``bark_heights`` circles (in place).

    A sparse scan shows a stem by a few points a centimetre, and undergrowth or the
    tree's own low branches can hide its lowest two metres: the inventory looks at
    such a stem again in slices twice as thick, up to ``AGAIN_HEIGHTS_M``, and keeps
    the look that shows more circles when they show one stem: radii within
    ``taper_tol`` of their median, centres within that radius of theirs (circles
    through a shrub or a crown's edge differ).
    """
    for k, fit in enumerate(fits):
        if fit is not None and len(fit.line) >= params.bark_heights:
            continue
        again = _measure_stem(pts, h, ground, seeds[k], params, again=True)
        if (
            again is not None
            and (fit is None or len(again.line) > len(fit.line))
            and _one_stem(again, params)
        ):
            fits[k] = again


def _one_stem(fit: _StemFit, params: StemMapParams) -> bool:
    """Tell whether a fit's circles agree as one stem's (see :func:`_look_again`)."""
    radii = np.array(list(fit.radii.values()))
    ref = float(np.median(radii))
    xy = np.array([c[1:] for c in fit.line])
    return bool(
        np.all(_same_width(radii, ref, params))
        and np.hypot(*(xy - np.median(xy, axis=0)).T).max() <= ref
    )


def _merge_same_stems(
    seeds: list[np.ndarray], fits: list[_StemFit | None], params: StemMapParams
) -> None:
    """Keep one fit of a stem found twice (in place): its seeds join the first.

    A stem can be found twice: in two pieces (two positions each see one side, too
    far apart to link in the slice), as a slice cluster and bark beside it, or again
    above its foot. Fits whose bases, or whose circles at one height, lie within
    ``same_stem_m`` are one stem: two fits of a leaning stem drawn down from
    different circles can put its base apart.
    """
    kept: list[tuple[int, _StemFit]] = []
    for k, fit in enumerate(fits):
        if fit is None:
            continue
        same = [j for j, other in kept if _same_stem(fit, other, params.same_stem_m)]
        if same:
            seeds[same[0]] = np.concatenate([seeds[same[0]], seeds[k]])
            fits[k] = None
        else:
            kept.append((k, fit))


def _same_stem(a: _StemFit, b: _StemFit, reach_m: float) -> bool:
    """Tell whether two fits' bases, or their circles at one height, lie within reach."""
    if np.hypot(*(a.stem.base[:2] - b.stem.base[:2])) <= reach_m:
        return True
    b_at = {at: (x, y) for at, x, y in b.line}
    return any(
        at in b_at and np.hypot(x - b_at[at][0], y - b_at[at][1]) <= reach_m
        for at, x, y in a.line
    )


def _add_hidden_stems(
    pts: np.ndarray,
    h: np.ndarray,
    ground: GroundFit,
    seeds: list[np.ndarray],
    fits: list[_StemFit | None],
    params: StemMapParams,
) -> None:
    """Add the stems whose foot is hidden to ``seeds`` and ``fits`` (in place).

    Undergrowth, or a spruce's own branches down to the ground, hide a stem in the
    slice; higher up its bark still shows. Bark seeds ``hidden_low_m``-
    ``hidden_high_m`` above the ground, farther than ``hidden_gap_m`` from every stem
    found, are such stems (one that measures to a stem's base joins it in
    :func:`_merge_same_stems`).
    """
    from scipy.spatial import cKDTree

    band = np.flatnonzero((h >= params.hidden_low_m) & (h <= params.hidden_high_m))
    found = [f.stem.dbh_xy for f in fits if f is not None]
    if found and len(band):
        gap = cKDTree(np.array(found)).query(pts[band, :2])[0]
        band = band[gap > params.hidden_gap_m]
    for seed in bark_seeds(pts, h, band, params):
        fit = _measure_stem(pts, h, ground, seed, params)
        if fit is not None:
            seeds.append(seed)
            fits.append(replace(fit, hidden=True))


def _add_wrapped_stems(
    pts: np.ndarray,
    h: np.ndarray,
    ground: GroundFit,
    slice_idx: np.ndarray,
    seeds: list[np.ndarray],
    fits: list[_StemFit | None],
    *,
    params: StemMapParams,
) -> None:
    """Add the stems wrapped in a conifer's branches to ``seeds``, ``fits`` (in place).

    A spruce's branches down to the ground can hide its stem from every position:
    its slice cluster, often wider than a stem's, shows no bark circle. Its whorls
    still radiate from the stem and hang all round it (:func:`branch_axis`,
    :func:`_skirt_sectors`): a slice cluster of no stem found that crosses the slice
    and has such an axis within ``WRAP_REACH_M``, farther than ``hidden_gap_m`` from
    every stem found, gets a stem on that axis, without DBH.
    """
    from amrst.stages.features import connected_components

    mine = [s for s, f in zip(seeds, fits, strict=True) if f is not None]
    rest = np.setdiff1d(slice_idx, np.concatenate([np.zeros(0, np.int64), *mine]))
    if len(rest) < params.bark_min_points:
        return
    found = np.array([f.stem.dbh_xy for f in fits if f is not None]).reshape(-1, 2)
    crown = np.flatnonzero(h >= AXIS_LOW_M)
    crown_xy = pts[crown, :2]
    skirt_xy = pts[(h >= SKIRT_HEIGHT_M[0]) & (h <= SKIRT_HEIGHT_M[1]), :2]
    lab = connected_components(pts[rest], params.scene.link_m)
    failed = [k for k, f in enumerate(fits) if f is None]
    for cluster in (rest[lab == k] for k in range(int(lab.max()) + 1)):
        if len(cluster) < params.bark_min_points or not crosses_slice(
            h[cluster], params.scene
        ):
            continue
        centre = np.median(pts[cluster, :2], axis=0)
        near = crown[np.hypot(*(crown_xy - centre).T) <= WRAP_REACH_M]
        axis = branch_axis(pts[near], h[near], centre)
        if axis is None or axis[1] < params.axis_support:
            continue
        xy = axis[0]
        if np.hypot(*(xy - centre)) > WRAP_REACH_M / 2 or (
            len(found) and np.hypot(*(found - xy).T).min() <= params.hidden_gap_m
        ):
            continue
        if _skirt_sectors(skirt_xy, xy) < params.skirt_sectors:
            continue
        nan = float("nan")
        stem = StemRecord(
            np.r_[xy, float(ground.surface_z(xy)[0])],
            xy,
            *(nan, nan, nan, nan, "none", nan, "not measured", nan, nan, len(cluster)),
            dbh_why=WRAPPED_WHY,
        )
        for j in failed:  # its points seed this stem alone
            seeds[j] = seeds[j][~np.isin(seeds[j], cluster)]
        seeds.append(cluster)
        fits.append(_StemFit(stem, [], {}, wrapped=True))
        found = np.vstack([found, xy])


def _add_given_stems(
    pts: np.ndarray,
    h: np.ndarray,
    ground: GroundFit,
    seeds: list[np.ndarray],
    fits: list[_StemFit | None],
    given: Mapping[str, tuple[float, float]],
    *,
    params: StemMapParams,
) -> dict[int, str]:
    """Add the technician's trees to ``seeds`` and ``fits`` (in place).

    Each point is tagged on its fit (``StemRecord.given``, the point's id).
    Returns each tagged fit's role: ``found``, a stem the map found within
    ``same_stem_m`` of the point (the nearest untagged one), listed as found when the
    inventory keeps it and as given when it does not; ``made``, a stem measured at the
    point from the points ``GIVEN_LOW_M``-``GIVEN_HIGH_M`` above the ground within
    ``GIVEN_REACH_M`` and nearer the point than any stem found (or, without such
    points, none), always listed as given. A point out of every scan's sight
    (``GIVEN_SEEN_M``) is not listed.
    """
    roles: dict[int, str] = {}
    found = [k for k, f in enumerate(fits) if f is not None]
    bases = np.array([f.stem.base[:2] for f in fits if f is not None]).reshape(-1, 2)
    band = np.flatnonzero((h >= GIVEN_LOW_M) & (h <= GIVEN_HIGH_M))
    for tree_id, point in given.items():
        xy = np.asarray(point, float)
        if not len(pts) or np.hypot(*(pts[:, :2] - xy).T).min() > GIVEN_SEEN_M:
            continue
        d = np.hypot(*(bases - xy).T)
        free = [j for j in np.argsort(d) if found[j] not in roles]
        if free and d[free[0]] <= params.same_stem_m:
            k = found[free[0]]
            old = fits[k]
            assert old is not None  # among the fits found
            fits[k] = replace(old, stem=replace(old.stem, given=tree_id))
            roles[k] = "found"
            continue
        near = band[np.hypot(*(pts[band, :2] - xy).T) <= GIVEN_REACH_M]
        mine = np.hypot(*(pts[near, :2] - xy).T)
        other = [np.hypot(*(pts[near, :2] - b).T) for b in bases]
        seed = near[mine < np.min(other, axis=0)] if other else near
        fit = _measure_stem(pts, h, ground, seed, params) if len(seed) else None
        nan = float("nan")
        bare = StemRecord(
            np.r_[xy, float(ground.surface_z(xy)[0])],
            xy,
            *(nan, nan, nan, nan, "none", nan, "not measured", nan, nan, 0),
        )
        roles[len(fits)] = "made"
        seeds.append(seed)
        fits.append(
            _StemFit(
                replace(bare, given=tree_id, dbh_why="no stem found there"), [], {}
            )
            if fit is None
            else replace(fit, stem=replace(fit.stem, given=tree_id))
        )
    return roles


def _as_tree_or_given(
    fit: _StemFit,
    pts: np.ndarray,
    h: np.ndarray,
    ground: GroundFit,
    mine: np.ndarray,
    params: StemMapParams,
    *,
    role: str,
) -> StemRecord | None:
    """Return the stem as the inventory lists it (None: not at all).

    ``role`` as :func:`_add_given_stems` gives it ("": no point of the technician's).
    A found stem the inventory keeps is a tree found, whatever point fell on it; a
    given one it would drop, or one made at a point, is listed as given.
    """
    stem = (
        _as_tree(fit, pts, h, ground, mine, params) if fit.line or fit.wrapped else None
    )
    if stem is not None and role != "made":
        return replace(stem, given=None)
    if stem is not None:
        return stem  # the tag rides on fit.stem through _as_tree
    return _given_tree(fit, pts, mine, params) if role else None


def _given_tree(
    fit: _StemFit, pts: np.ndarray, mine: np.ndarray, params: StemMapParams
) -> StemRecord:
    """Return the technician's tree as it stands: its height, crown and points."""
    top, crown, n_top = _top_and_crown(pts[mine])
    return replace(
        fit.stem,
        height_m=top[2] - fit.stem.base[2],
        height_flag=_height_flag(fit.stem, top, n_top, params),
        crown_width_m=crown,
        n_points=int(mine.sum()),
    )


def bark_seeds(
    pts: np.ndarray, h: np.ndarray, rest: np.ndarray, params: StemMapParams
) -> list[np.ndarray]:
    """Stems inside the slice clusters that are no stem as a whole.

    A stem among shrubs or its own low branches makes one cluster too wide to be a
    stem; its bark still shows as an upright, smooth surface: such points, linked
    within ``bark_link_m``, that rise ``bark_min_rise_m`` within a narrow footprint,
    are the stem.
    """
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components
    from scipy.spatial import cKDTree

    if len(rest) < params.bark_min_points:
        return []
    bark = rest[stem_surface(pts[rest], 0.0, np.inf)]
    if len(bark) < params.bark_min_points:
        return []
    pairs = cKDTree(pts[bark]).query_pairs(params.bark_link_m, output_type="ndarray")
    graph = coo_matrix(
        (np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])), shape=(len(bark),) * 2
    )
    n, lab = connected_components(graph, directed=False)
    seeds = []
    for k in range(n):
        idx = bark[lab == k]
        if (
            len(idx) >= params.bark_min_points
            and np.ptp(h[idx]) >= params.bark_min_rise_m
            and np.ptp(pts[idx, :2], axis=0).max() <= params.bark_max_width_m
        ):
            seeds.append(idx)
    return seeds


@dataclass(frozen=True, slots=True)
class _StemFit:
    """A stem measured on its bark circles, and the circles: (height, x, y), radii."""

    stem: StemRecord
    line: list[tuple[float, float, float]]
    radii: dict[float, float]
    hidden: bool = False  # found above its foot (see _add_hidden_stems)
    wrapped: bool = False  # no circle: on its branch axis (see _add_wrapped_stems)


def _measure_stem(
    pts: np.ndarray,
    h: np.ndarray,
    ground: GroundFit,
    seed: np.ndarray,
    params: StemMapParams,
    *,
    again: bool = False,
) -> _StemFit | None:
    """Measure one stem (``seed``: its slice points): base, DBH, lean.

    ``again``: the second look at a stem that showed too few circles
    (:func:`_look_again`), in slices twice as thick and up to ``AGAIN_HEIGHTS_M``.

    None when bark circles fit at fewer than ``min_circles`` heights: a shrub or a
    hanging branch crosses the slice too, but it is no upright stem.
    """
    heights = AGAIN_HEIGHTS_M if again else LINE_HEIGHTS_M
    lo = pts[seed, :2].min(axis=0) - STEM_MARGIN_M
    hi = pts[seed, :2].max(axis=0) + STEM_MARGIN_M
    box = np.flatnonzero(
        np.all((pts[:, :2] >= lo) & (pts[:, :2] <= hi), axis=1)
        & (h > 0.3)
        & (h < max(heights) + 0.3)
    )
    near, hn = pts[box], h[box]
    centre = pts[seed, :2].mean(axis=0)
    z0 = float(ground.surface_z(centre)[0])
    mp = MeasureParams(inlier_m=params.circle_inlier_m, max_radius_m=1.0)
    thick = 2.0 if again else 1.0
    half = thick * (params.dbh_high_m - params.dbh_low_m) / 2
    dbh_h = (params.dbh_low_m + params.dbh_high_m) / 2
    line: list[tuple[float, float, float]] = []
    radii: dict[float, float] = {}
    dbh_fit: tuple[StemCircle, float] | None = None
    for at in sorted({*heights, dbh_h}):
        width = half if at == dbh_h else thick * 0.05
        in_slice = np.abs(hn - at) <= width
        if in_slice.sum() < 12:
            continue
        bark = stem_surface(near, z0 + at, width)
        circle = fit_stem_circle(near[in_slice & bark, :2], mp)
        if circle is None:
            continue
        line.append((at, *circle.centre_xy))
        radii[at] = circle.radius_m
        if at == dbh_h:
            dbh_fit = (circle, _outlier_share(near[in_slice, :2], circle))
    if len(line) < params.min_circles:
        return None
    base_xy, _, lean = _stem_line(line, centre)
    base_xy = _foot_xy(line, base_xy)
    base = np.r_[base_xy, float(ground.surface_z(base_xy)[0])]
    nan = float("nan")
    quality, why = _dbh_quality(dbh_fit, params, tapers=_tapers(radii, dbh_h, params))
    stem = StemRecord(
        base=base,
        dbh_xy=np.asarray(dbh_fit[0].centre_xy) if dbh_fit else base_xy,
        dbh_m=2 * dbh_fit[0].radius_m if dbh_fit else nan,
        arc_deg=dbh_fit[0].arc_deg if dbh_fit else nan,
        rmse_m=dbh_fit[0].rmse_m if dbh_fit else nan,
        outlier_share=dbh_fit[1] if dbh_fit else nan,
        dbh_quality=quality,
        dbh_why=why,
        height_m=nan,
        height_flag="not measured",
        lean_deg=lean,
        crown_width_m=nan,
        n_points=len(seed),
    )
    return _StemFit(stem, line, radii)


def _as_tree(
    fit: _StemFit,
    pts: np.ndarray,
    h: np.ndarray,
    ground: GroundFit,
    mine: np.ndarray,
    params: StemMapParams,
) -> StemRecord | None:
    """Measure the stem as a tree of the inventory: DBH over slices, height, flags.

    None when the tree is lower than ``min_height_m`` (a shrub), or its stem shows
    bark circles at fewer than ``bark_heights`` heights and it is lower than
    ``hidden_tree_m`` (a branch tip or a bush, not a tree with a hidden stem).
    """
    top, crown, n_top = _top_and_crown(pts[mine])
    top_h = top[2] - fit.stem.base[2]
    if not top_h >= params.min_height_m:
        return None
    if len(fit.line) < params.bark_heights and not top_h >= params.hidden_tree_m:
        return None
    conifer = fit.wrapped
    if fit.wrapped:
        stem, _ = _on_branch_axis(fit.stem, pts[mine], h[mine], ground, params)
        stem = replace(stem, dbh_xy=stem.base[:2], dbh_why=WRAPPED_WHY)
    else:
        stem = _taper_stem(fit, pts, h, ground, params)
        foot_r = fit.radii.get(LINE_HEIGHTS_M[0], np.inf)
        if (
            fit.hidden
            or 2 * foot_r > params.wide_foot_m
            or _scattered(fit.line, params)
        ):
            stem, conifer = _on_branch_axis(stem, pts[mine], h[mine], ground, params)
    return replace(
        stem,
        height_m=top_h,
        height_flag=_height_flag(stem, top, n_top, params, conifer=conifer),
        crown_width_m=crown,
        n_points=int(mine.sum()),
    )


def _taper_stem(
    fit: _StemFit,
    pts: np.ndarray,
    h: np.ndarray,
    ground: GroundFit,
    params: StemMapParams,
) -> StemRecord:
    """Measure the DBH on the taper line and fit the stem line to its circles.

    The stem line is fitted again to the circles on the taper line (slice circles
    and bark circles that agree with it): a circle through a branch no longer tilts
    it. The DBH needs ``taper_min_circles`` slice circles on the line, all but
    ``taper_misfits`` of those fitted, and a bark circle that agrees with it; else the
    stem has none: circles through the twigs and branches of a thin or hidden stem
    agree by chance, those of a lobed or buttressed one tell several diameters, and one
    wrong diameter weighs more than a missing one. A stem without slice circles keeps
    its bark circle's DBH, unless it was found above its foot.
    """
    base_xy, slope, _ = _stem_line(fit.line, fit.stem.base[:2])
    radius = float(np.median(list(fit.radii.values()))) if fit.radii else 0.15
    reach = radius + WINDOW_MARGIN_M + float(np.linalg.norm(slope)) * 1.6
    around = np.flatnonzero(
        (np.abs(h - BREAST_HEIGHT_M) <= 0.4)
        & (np.hypot(*(pts[:, :2] - (base_xy + slope * BREAST_HEIGHT_M)).T) <= reach)
    )
    taper = taper_dbh(
        pts[around], h[around], (base_xy, slope), radius, params.circle_inlier_m
    )
    bark = (
        []
        if taper is None
        else [
            (at, x, y) for at, x, y in fit.line if taper.agrees(at, 2 * fit.radii[at])
        ]
    )
    if taper is None:
        if fit.hidden:
            return replace(_without_dbh(fit.stem), dbh_why="no circle at 1.0-1.6 m")
        return fit.stem
    on_line = [(at, *c.centre_xy) for at, c in taper.circles] + bark
    base_xy, _, lean = _stem_line(sorted(on_line), base_xy, params.refit_circles)
    # A foot circle far wider than the stem above it went round a buttress or a root.
    foot = [c for c in fit.line if 2 * fit.radii[c[0]] <= FOOT_WIDER * taper.at(c[0])]
    base_xy = _foot_xy(foot, base_xy)
    # Too few circles on the taper line leave the lean unmeasured (NaN): the first
    # fit's line went through circles the taper line rejects.
    stem = replace(
        fit.stem,
        base=np.r_[base_xy, float(ground.surface_z(base_xy)[0])],
        lean_deg=lean,
    )
    enough = max(params.taper_min_circles, taper.fitted - params.taper_misfits)
    if len(taper.circles) < enough:
        return replace(
            _without_dbh(stem),
            dbh_why=f"{len(taper.circles)} of {taper.fitted} slice circles agree "
            f"(twigs, a buttress?), {enough} needed",
        )
    if not bark:
        return replace(
            _without_dbh(stem),
            dbh_why="no bark circle 0.6-2.2 m up agrees with the slice circles",
        )
    if taper.dbh_m > params.wide_stem_m and taper.circle.arc_deg < params.wide_arc_deg:
        return replace(
            _without_dbh(stem),
            arc_deg=taper.circle.arc_deg,
            dbh_why=f"a wide stem seen on {taper.circle.arc_deg:.0f}°, "
            f"{params.wide_arc_deg:g}° needed",
        )
    outliers = _outlier_share(taper.slice_xy, taper.circle)
    # The taper's circle lies on the line with its neighbours by construction.
    quality, why = _dbh_quality((taper.circle, outliers), params, tapers=True)
    return replace(
        stem,
        dbh_xy=np.asarray(taper.circle.centre_xy),
        dbh_m=taper.dbh_m,
        arc_deg=taper.circle.arc_deg,
        rmse_m=taper.circle.rmse_m,
        outlier_share=outliers,
        dbh_quality=quality,
        dbh_why=why,
    )


def _scattered(line: list[tuple[float, float, float]], params: StemMapParams) -> bool:
    """Tell whether a stem's circles scatter round their median centre.

    Farther than ``scattered_line_m``: circles through a spruce's branches do, a
    stem's lie on a line.
    """
    xy = np.array([c[1:] for c in line], float).reshape(-1, 2)
    if not len(xy):
        return False
    return (
        float(np.hypot(*(xy - np.median(xy, axis=0)).T).max()) > params.scattered_line_m
    )


def _on_branch_axis(
    stem: StemRecord,
    tree: np.ndarray,
    h: np.ndarray,
    ground: GroundFit,
    params: StemMapParams,
) -> tuple[StemRecord, bool]:
    """Return the stem with its base where its branches point, and whether it moved.

    Branches down to the ground hide a spruce's stem: the circles found through them
    lie up to a metre off, while its whorls still radiate from the stem. The stem
    moves only when ``axis_support`` of its branch lines pass the axis found and its
    own low branches surround that axis (``skirt_sectors``): a broadleaf's branches
    do not meet at one point, nor hang around it near the ground. A breast-height
    circle farther than ``same_stem_m`` from the axis measured branches: no DBH. A
    stem that moves is a conifer's.
    """
    axis = branch_axis(tree, h, stem.base[:2])
    if axis is None or axis[1] < params.axis_support:
        return stem, False
    skirt = (h >= SKIRT_HEIGHT_M[0]) & (h <= SKIRT_HEIGHT_M[1])
    if _skirt_sectors(tree[skirt, :2], axis[0]) < params.skirt_sectors:
        return stem, False
    base = np.r_[axis[0], float(ground.surface_z(axis[0])[0])]
    if np.hypot(*(stem.dbh_xy - axis[0])) <= params.same_stem_m:
        return replace(stem, base=base), True
    # Its breast-height circle went round branches: no DBH, and no lean measured.
    nan = float("nan")
    return replace(
        _without_dbh(stem),
        base=base,
        dbh_xy=axis[0],
        lean_deg=nan,
        dbh_why="the circle went round branches",
    ), True


def _skirt_sectors(xy: np.ndarray, axis: np.ndarray) -> int:
    """Count the 12 directions round ``axis`` in which points hang ``SKIRT_REACH_M``."""
    v = xy - axis
    r = np.hypot(v[:, 0], v[:, 1])
    v = v[(r >= SKIRT_REACH_M[0]) & (r <= SKIRT_REACH_M[1])]
    angle = np.arctan2(v[:, 1], v[:, 0])
    return len(np.unique(np.floor((angle + np.pi) / (2 * np.pi) * 12).astype(int) % 12))


def branch_axis(
    tree: np.ndarray, h: np.ndarray, start: np.ndarray
) -> tuple[np.ndarray, float] | None:
    """Return where a tree's branches point (x, y) and the share of them that do.

    A conifer's whorls radiate from its stem: the horizontal lines of its branches
    meet at the stem even where no scan saw the stem. The point nearest all lines
    (least squares on their normals, Cauchy weights of ``AXIS_NEAR_M``, from
    ``start``); None with fewer than 20 branch lines.
    """
    from scipy.spatial import cKDTree

    from amrst.stages.voxels import voxel_sample

    top = float(h.max()) if len(h) else 0.0
    crown = (h >= AXIS_LOW_M) & (h <= AXIS_LOW_M + AXIS_HIGH_SHARE * (top - AXIS_LOW_M))
    if crown.sum() < 50:
        return None
    pts = tree[crown]
    pts = pts[np.asarray(voxel_sample(pts, AXIS_VOXEL_M))]
    dist, nb = cKDTree(pts).query(pts, k=16, distance_upper_bound=AXIS_RADIUS_M)
    ok = np.isfinite(dist)  # a missing neighbour has index len(pts)
    count = ok.sum(axis=1)
    keep = count >= 6
    if keep.sum() < 20:
        return None
    ok, nb, count = ok[keep], nb[keep], count[keep]
    near = pts[np.where(ok, nb, 0)] * ok[..., None]
    mean = near.sum(axis=1) / count[:, None]
    d = (near - mean[:, None]) * ok[..., None]
    cov = np.einsum("nki,nkj->nij", d, d) / count[:, None, None]
    w, vec = np.linalg.eigh(cov)  # ascending
    main = vec[:, :, 2]
    level = np.hypot(main[:, 0], main[:, 1])
    line = (w[:, 2] > 0) & ((w[:, 2] - w[:, 1]) >= AXIS_LINEAR * w[:, 2])
    line &= level >= AXIS_LEVEL
    if line.sum() < 20:
        return None
    p = pts[keep][line, :2]
    u = main[line, :2] / level[line, None]
    normal = np.column_stack([-u[:, 1], u[:, 0]])
    offset = np.sum(normal * p, axis=1)
    c = np.asarray(start, dtype=float)
    for _ in range(10):
        r = np.hypot(*(p - c).T)
        wt = ((r > AXIS_RANGE_M[0]) & (r < AXIS_RANGE_M[1])) / (
            1.0 + ((normal @ c - offset) / AXIS_NEAR_M) ** 2
        )
        a = (normal * wt[:, None]).T @ normal
        if np.linalg.cond(a) > 1e6:
            return None
        c = np.linalg.solve(a, (normal * wt[:, None]).T @ offset)
    r = np.hypot(*(p - c).T)
    band = (r > AXIS_RANGE_M[0]) & (r < AXIS_RANGE_M[1])
    if not band.any():
        return None
    return c, float(np.mean(np.abs(normal[band] @ c - offset[band]) <= AXIS_NEAR_M))


def _without_dbh(stem: StemRecord) -> StemRecord:
    """Return the stem with no DBH (``none``), nor the arc and fit of one."""
    nan = float("nan")
    return replace(
        stem,
        dbh_m=nan,
        arc_deg=nan,
        rmse_m=nan,
        outlier_share=nan,
        dbh_quality="none",
        dbh_why="",
    )


def _outlier_share(xy: np.ndarray, circle: StemCircle) -> float:
    """Share of the slice points near the circle (``OUTLIER_NEAR_M``) off it.

    Off: over ``OUTLIER_OFF_M``. Points farther than ``OUTLIER_NEAR_M`` are other
    things (a neighbour, a branch end) and do not count.
    """
    d = np.abs(np.linalg.norm(xy - circle.centre_xy, axis=1) - circle.radius_m)
    near = d <= OUTLIER_NEAR_M
    return float(np.mean(d[near] > OUTLIER_OFF_M)) if near.any() else 1.0


def _tapers(radii: dict[float, float], dbh_h: float, params: StemMapParams) -> bool:
    """Tell whether the DBH circle agrees with the stem's circles below and above it.

    A circle through a branch or a buttress differs from its neighbours, the stem
    tapers slowly; with no neighbour circle there is nothing to check against.
    """
    if dbh_h not in radii:
        return False
    others = [r for at, r in radii.items() if at != dbh_h and abs(at - dbh_h) <= 0.5]
    if not others:
        return True
    return bool(_same_width(radii[dbh_h], float(np.median(others)), params))


def _same_width(
    radius: float | np.ndarray, ref: float, params: StemMapParams
) -> np.ndarray:
    """Tell whether a circle of ``radius`` is one stem's with one of ``ref`` (m)."""
    return np.asarray(np.abs(radius - ref) <= params.taper_tol * ref + 0.005)


def _dbh_quality(
    fit: tuple[StemCircle, float] | None,
    params: StemMapParams,
    *,
    tapers: bool,
) -> tuple[str, str]:
    """Return the DBH's quality and, for ``check``, what failed (``dbh_why``).

    ``tapers``: the circle agrees with the stem's circles near it.
    """
    if fit is None:
        return "none", "no circle at breast height"
    circle, outliers = fit
    wide = 2 * circle.radius_m > params.wide_stem_m
    arc = params.wide_ok_arc_deg if wide else params.ok_arc_deg
    why = []
    # Written as "not good" so that a NaN figure fails too.
    if not circle.arc_deg >= arc:
        why.append(f"bark seen on {circle.arc_deg:.0f}° of the stem, {arc:g}° needed")
    if not circle.rmse_m <= params.ok_rmse_m:
        why.append(
            f"points {circle.rmse_m * 1000:.1f} mm off the circle, "
            f"{params.ok_rmse_m * 1000:g} mm allowed"
        )
    if not outliers <= params.ok_outlier_share:
        why.append(
            f"{outliers:.0%} of the points near the circle off it, "
            f"{params.ok_outlier_share:.0%} allowed"
        )
    if not tapers:
        why.append("slices 1.0-1.6 m disagree")
    return ("check" if why else "ok"), "; ".join(why)


def _stem_line(
    line: list[tuple[float, float, float]], centre: np.ndarray, min_circles: int = 3
) -> tuple[np.ndarray, np.ndarray, float]:
    """Return the base (x, y) at height 0, the shift per metre up and the lean (deg).

    ``line`` holds (height above the ground, x, y) of each slice's circle; fewer than
    ``min_circles`` circles, or spread over less than 0.5 m of height, make an
    upright stem through their mean centre, its lean NaN (not measured).
    """
    if not line:
        return centre, np.zeros(2), float("nan")
    a = np.asarray(line)
    if len(a) < min_circles or np.ptp(a[:, 0]) < 0.5:
        return np.asarray(a[:, 1:].mean(axis=0)), np.zeros(2), float("nan")
    A = np.column_stack([a[:, 0], np.ones(len(a))])
    coef = np.linalg.lstsq(A, a[:, 1:], rcond=None)[0]  # rows: slope, intercept
    lean = float(np.degrees(np.arctan(np.linalg.norm(coef[0]))))
    return np.asarray(coef[1]), np.asarray(coef[0]), lean


def _foot_xy(line: list[tuple[float, float, float]], line_xy: np.ndarray) -> np.ndarray:
    """Return the stem's foot: its circle's centre 0.6 m up, else ``line_xy``.

    The centre ``LINE_HEIGHTS_M[0]`` up is nearer the foot than the stem line drawn
    down to the ground: a lean fitted on circles a few centimetres off, over a metre
    or two of stem, tilts the line more than most stems lean.
    """
    low = [(x, y) for at, x, y in line if at == LINE_HEIGHTS_M[0]]
    return np.asarray(low[0]) if low else line_xy


def _top_and_crown(tree: np.ndarray) -> tuple[np.ndarray, float, int]:
    """Return the top (highest point with neighbours), crown width, top metre points."""
    if len(tree) < 3:
        return np.full(3, np.nan), float("nan"), 0
    from amrst.measure import measure_tree

    m = measure_tree(tree, replace(MeasureParams(), iterations=10))
    top = tree_top(tree)
    n_top = int(np.sum(tree[:, 2] >= top[2] - 1.0))
    return top, m.crown_width_m, n_top


def _height_flag(
    stem: StemRecord,
    top: np.ndarray,
    n_top: int,
    params: StemMapParams,
    *,
    conifer: bool = False,
) -> str:
    """Flag a tree's height (``StemMapParams``' height flags), found or given.

    ``conifer``: the stem stands where its branches point (:func:`_on_branch_axis`).
    """
    if not n_top:
        return "not measured"
    if n_top < params.min_top_points:
        return "top not seen"
    off = float(np.hypot(top[0] - stem.base[0], top[1] - stem.base[1]))
    top_lean = float(np.degrees(np.arctan2(off, top[2] - stem.base[2])))
    if stem.lean_deg > params.lean_flag_deg or top_lean > params.top_lean_flag_deg:
        return "lean"
    return "lean" if conifer and off > params.conifer_top_off_m else "ok"
