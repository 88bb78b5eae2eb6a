"""Forest plots for the virtual scanner: real trees scanned from several positions.

:func:`plot_scene` stands complete trees on a plot (the pieces of
:mod:`amrst.simulate.field`):

- each tree turned to a random heading and scaled by a random factor
  (``scale``, 0.85-1.15), its foot at least ``min_gap_m`` from every other foot and
  within ``plot_radius_m`` of the plot centre;
- ``positions`` tripod positions inside the plot, each ``spacing_m`` from the one
  before, clear of the stems;
- a rough, gently sloped ground disc reaching ``range_m`` beyond the plot, and
  ``shrubs`` leafy blobs.

:func:`simulate_plot` scans it from every position with the virtual scanner of
:mod:`amrst.simulate` (the scanner ``height_m`` above the ground under it); each scan
keeps what lies within ``range_m`` of the scanner and is written in its own frame. The
truth: ``T_scan1_scank`` (scan k into scan 1) and every tree's stem foot, DBH and
height, measured on the complete placed tree.

Kinds (:func:`plot_options`): ``normal`` (positions 6-12 m apart, tilt up to 0.3 deg),
``hard`` (12-16 m, up to 2 deg), ``sparse`` (the scans after the first at twice the
beam step: a quarter of the points) and ``wind`` (every crown swayed by 8-15 cm at the
top in each scan after the first).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import TYPE_CHECKING, Any

import numpy as np

from amrst.errors import InvalidInput
from amrst.progress import NULL_REPORTER, Reporter, SubReporter
from amrst.simulate import (
    MIN_POINTS,
    check_case_folder,
    footprints,
    scanner_pose,
    simulate_scan,
)
from amrst.simulate.field import (
    ground_disc,
    ground_height,
    shrub,
    standing,
    with_relief,
)
from amrst.simulate.settings import MIN_TREES, check_numbers, check_range
from amrst.types import Cloud, Transform, apply_transform, invert_transform

if TYPE_CHECKING:
    import os
    from collections.abc import Callable, Sequence
    from pathlib import Path

# A tree cloud shorter than this (m) is no tree to plant (one point, a shrub).
MIN_TREE_HEIGHT_M = 1.0
# Most ground points a plot simulation builds in memory (the defaults make about
# 1.3 million).
MAX_GROUND_POINTS = 8_000_000
# A tripod stands at least this far from every stem foot (buttresses, the trunk).
_STEM_CLEARANCE_M = 1.5
#: The plot's hills (``PlotOptions.relief_m``) are drawn from the seed's own stream.
RELIEF_STREAM = 7
# Tries to place one tree or one scanner position before giving up.
_TRIES = 2000
# DBH truth: the slice above the foot, the circle's band, the share of the circle
# its inliers must cover (else the stem has no clear circle: NaN), the fewest inliers,
# the RANSAC samples and the largest stem radius.
_SLICE_M = (1.25, 1.35)
_CIRCLE_BAND_M = 0.01
_MIN_ARC_SHARE = 0.6
_MIN_RING_POINTS = 12
_RANSAC_TRIES = 2000
_MAX_STEM_RADIUS_M = 1.0
# Height truth: a point with no other point of its tree this close (m) is a stray of
# the source cloud (one tree file holds points metres off its crown), not its top.
_STRAY_M = 1.0
# Azimuth sectors a scan is computed in: the beam grid of a whole plot scan at once
# would hold a few hundred million cell entries.
_SECTORS = 16

KINDS: dict[str, dict[str, Any]] = {
    "normal": {},
    "hard": {"spacing_m": (12.0, 16.0), "tilt_deg": 2.0},
    "sparse": {"sparse": True},
    "wind": {"sway_m": (0.08, 0.15)},
}


@dataclass(frozen=True, slots=True, kw_only=True)
class PlotOptions:
    """How the plot is laid out and scanned (the defaults are the ``normal`` kind).

    The settings a command option sets are checked by
    :func:`amrst.simulate.settings.check_numbers`, with the ranges it names.

    kind : str
        Recorded in the truth; :func:`plot_options` sets the fields of a kind.
    positions : int
        Tripod positions (2 or more).
    spacing_m : (float, float)
        Range of the distance from each position to the one before (m).
    tilt_deg : float
        Largest residual tilt of each scanner; drawn uniformly up to it (deg).
    res_deg, noise_m, height_m : float
        Beam grid step (deg), range noise sigma (m), scanner height above the ground.
    sparse : bool
        The scans after the first at twice ``res_deg``.
    sway_m : (float, float)
        Range of each crown's sway at the tree top in every scan after the first
        (m; zero: no wind). The sway grows with the square of the height.
    trees : int or None
        Trees to place, drawn from the given ones without repetition (None: all).
    plot_radius_m, min_gap_m, scale : float, float, (float, float)
        Stem feet within this radius of the centre, at least this far apart; each
        tree scaled by a factor drawn in ``scale``.
    range_m : float
        Each scan keeps what lies within this distance of the scanner (m).
    ground_spacing_m, slope_deg, roughness_m : float
        Ground point spacing, largest slope, bump height.
    relief_m : float
        Height of the terrain's hills and hollows, 5-15 m across (zero: none); they
        are drawn apart from the rest, so a plot keeps its trees and scans with them.
    shrubs : int
        Leafy blobs inside the plot or up to 4 m beyond its edge.
    """

    kind: str = "normal"
    positions: int = 2
    spacing_m: tuple[float, float] = (6.0, 12.0)
    tilt_deg: float = 0.3
    res_deg: float = 0.04
    noise_m: float = 0.004
    height_m: float = 1.5
    sparse: bool = False
    sway_m: tuple[float, float] = (0.0, 0.0)
    trees: int | None = None
    plot_radius_m: float = 10.0
    min_gap_m: float = 3.0
    scale: tuple[float, float] = (0.85, 1.15)
    range_m: float = 22.0
    ground_spacing_m: float = 0.05
    slope_deg: float = 8.0
    roughness_m: float = 0.04
    relief_m: float = 0.0
    shrubs: int = 15

    def __post_init__(self) -> None:
        check_numbers(
            {
                name: getattr(self, name)
                for name in (
                    "positions",
                    "tilt_deg",
                    "res_deg",
                    "noise_m",
                    "height_m",
                    "range_m",
                    "slope_deg",
                    "relief_m",
                    "shrubs",
                    "trees",
                )
            },
            optional=True,  # trees None: as many as the tree files
        )
        check_range("spacing_m", self.spacing_m)
        # The layout's own numbers (no command option sets them).
        numbers = {
            "sway_m": self.sway_m,
            "plot_radius_m": (self.plot_radius_m,),
            "min_gap_m": (self.min_gap_m,),
            "scale": self.scale,
            "ground_spacing_m": (self.ground_spacing_m,),
            "roughness_m": (self.roughness_m,),
        }
        for name, values in numbers.items():
            if not all(math.isfinite(v) for v in values):
                raise InvalidInput(f"{name} must be finite, got {values}.")
        lo, hi = self.scale
        if not 0 < lo <= hi:
            raise InvalidInput(
                f"scale must be a range with 0 < low <= high, got {lo} and {hi}."
            )
        self._check_scene()

    def _check_scene(self) -> None:
        if min(self.plot_radius_m, self.ground_spacing_m) <= 0:
            raise InvalidInput("plot_radius_m and ground_spacing_m must be > 0.")
        if min(self.min_gap_m, self.roughness_m, *self.sway_m) < 0:
            raise InvalidInput("min_gap_m, roughness_m and sway_m must be >= 0.")
        reach = self.plot_radius_m + self.range_m  # the ground disc's radius
        across = reach / self.ground_spacing_m
        ground = math.pi * across * across  # inf, not an overflow, when huge
        if ground > MAX_GROUND_POINTS:
            count = f"{ground:,.0f}" if ground < 1e12 else f"{ground:.1e}"
            raise InvalidInput(
                f"A ground reaching {reach:g} m at {self.ground_spacing_m:g} m spacing "
                f"holds {count} points, more than {MAX_GROUND_POINTS:,}: give a "
                "shorter --range-m (plot scans keep 20-30 m)."
            )


def plot_options(kind: str = "normal", **changes: Any) -> PlotOptions:
    """Return the options of a plot ``kind`` (see :data:`KINDS`), with ``changes``.

    Raises
    ------
    InvalidInput
        An unknown kind, or options out of range.
    """
    if kind not in KINDS:
        raise InvalidInput(f"Unknown plot kind {kind!r}; choose from {list(KINDS)}.")
    return replace(PlotOptions(kind=kind, **KINDS[kind]), **changes)


@dataclass(frozen=True, slots=True)
class PlotTree:
    """One placed tree, measured on its complete (unscanned) points, plot frame."""

    name: str
    foot: np.ndarray  # (3,) stem foot: x, y, and the ground height there
    dbh_m: float  # NaN where no circle covers 60 % of the breast-height slice
    height_m: float  # top of the tree above its foot, its stray points left out


@dataclass(frozen=True, slots=True)
class PlotScene:
    """Every point of the plot (centre at the xy origin), and what was placed."""

    cloud: Cloud
    tree_of: np.ndarray  # (N,) int64: index into ``trees``, -1 for ground and shrubs
    trees: tuple[PlotTree, ...]
    positions: np.ndarray  # (P, 3): the ground point under each scanner


@dataclass(frozen=True, eq=False)
class SimulatedPlot:
    """The scans of a plot, each in its scanner frame, and the exact truth.

    ``poses[k]`` maps scan k's coordinates into the plot frame; ``specs[k]`` says how
    scan k was made (``azimuth_deg`` and ``distance_m`` from the plot centre, then as
    :func:`amrst.simulate.simulate_pair`).
    """

    scans: tuple[Cloud, ...]
    poses: tuple[Transform, ...]
    specs: tuple[dict[str, float], ...]
    trees: tuple[PlotTree, ...]
    kind: str

    def T_scan1_scank(self) -> list[Transform]:
        """Return the transforms that map scan k into scan 1, for every k."""
        inv = invert_transform(self.poses[0])
        return [inv @ pose for pose in self.poses]


def _place_feet(rng: np.random.Generator, n: int, options: PlotOptions) -> np.ndarray:
    feet: list[np.ndarray] = []
    for _ in range(_TRIES * n):
        if len(feet) == n:
            break
        xy = _in_disc(rng, options.plot_radius_m)
        if all(np.hypot(*(xy - f)) >= options.min_gap_m for f in feet):
            feet.append(xy)
    if len(feet) < n:
        raise InvalidInput(
            f"Cannot place {n} trees at least {options.min_gap_m:g} m apart within "
            f"{options.plot_radius_m:g} m of the plot centre; place fewer trees."
        )
    return np.array(feet)


def _in_disc(rng: np.random.Generator, radius: float) -> np.ndarray:
    """Draw a point uniformly in the disc of ``radius`` about the origin."""
    r, a = radius * np.sqrt(rng.uniform()), rng.uniform(0.0, 2 * np.pi)
    return np.array([r * np.cos(a), r * np.sin(a)])


def _place_positions(
    rng: np.random.Generator, feet: np.ndarray, options: PlotOptions
) -> np.ndarray:
    """Walk the tripod positions inside the plot, clear of the stems.

    Each position lies ``spacing_m`` from the one before and at least half the
    shortest spacing from all earlier ones (a walk does not come back to a spot).
    """
    lo, hi = options.spacing_m

    def clear(xy: np.ndarray, walk: list[np.ndarray]) -> bool:
        return bool(
            np.hypot(*xy) <= options.plot_radius_m
            and np.hypot(*(feet - xy).T).min() >= _STEM_CLEARANCE_M
            and all(np.hypot(*(xy - p)) >= lo / 2 for p in walk)
        )

    for _ in range(_TRIES):
        walk = [_in_disc(rng, options.plot_radius_m)]
        if not clear(walk[0], []):
            continue
        while len(walk) < options.positions:
            for _ in range(_TRIES // 10):
                a = rng.uniform(0.0, 2 * np.pi)
                xy = walk[-1] + rng.uniform(lo, hi) * np.array([np.cos(a), np.sin(a)])
                if clear(xy, walk):
                    walk.append(xy)
                    break
            else:
                break
        if len(walk) == options.positions:
            return np.array(walk)
    raise InvalidInput(
        f"Cannot place {options.positions} scanner positions {lo:g}-{hi:g} m apart "
        f"within {options.plot_radius_m:g} m of the plot centre, {_STEM_CLEARANCE_M} m "
        "from every stem; use fewer positions or a shorter spacing."
    )


def _measure(
    name: str, xyz: np.ndarray, foot: np.ndarray, rng: np.random.Generator
) -> PlotTree:
    """Measure one placed tree for the truth: DBH on its breast-height slice, height."""
    z = xyz[:, 2] - foot[2]
    ring = xyz[(z >= _SLICE_M[0]) & (z <= _SLICE_M[1]), :2]
    return PlotTree(name, foot, _ring_dbh_m(ring, rng), _top_m(xyz) - float(foot[2]))


def _top_m(xyz: np.ndarray) -> float:
    """Height (z) of the highest point of ``xyz`` that is no stray (see ``_STRAY_M``)."""
    from scipy.spatial import cKDTree

    order = np.argsort(-xyz[:, 2])
    tree = cKDTree(xyz)
    for start in range(0, len(order), 256):
        top = order[start : start + 256]
        near = tree.query(xyz[top], k=2)[0][:, 1] <= _STRAY_M
        if near.any():
            return float(xyz[top[np.argmax(near)], 2])
    return float(xyz[order[0], 2])


def _ring_dbh_m(ring: np.ndarray, rng: np.random.Generator) -> float:
    """Return the diameter of the circle most points of ``ring`` (M, 2) lie on.

    RANSAC on three-point circles, then a fit to the inliers of the best one; NaN when
    its inliers leave more than 40 % of the circle's 10-degree sectors empty
    (buttresses, branches in the slice, too few points). Most inliers, not the arc
    weighting of :func:`amrst.measure.stem.fit_stem_circle`: on a complete tree the
    stem is the best supported circle, and a wide circle through branch tips is not.
    """
    from amrst.measure.stem import _circles, _refine_circle

    if len(ring) < _MIN_RING_POINTS:
        return float("nan")
    pts = ring - ring.mean(axis=0)
    centres, radii = _circles(pts[rng.integers(0, len(pts), (_RANSAC_TRIES, 3))])
    ok = np.isfinite(radii) & (radii > 0.005) & (radii <= _MAX_STEM_RADIUS_M)
    if not ok.any():
        return float("nan")
    centres, radii = centres[ok], radii[ok]
    counts = np.concatenate(
        [
            np.sum(
                np.abs(
                    np.linalg.norm(pts[None] - centres[k : k + 256, None], axis=2)
                    - radii[k : k + 256, None]
                )
                <= _CIRCLE_BAND_M,
                axis=1,
            )
            for k in range(0, len(radii), 256)
        ]
    )
    best = int(np.argmax(counts))
    inl = np.abs(np.linalg.norm(pts - centres[best], axis=1) - radii[best])
    centre, radius = _refine_circle(
        pts[inl <= _CIRCLE_BAND_M], centres[best], radii[best], _CIRCLE_BAND_M
    )
    on = pts[np.abs(np.linalg.norm(pts - centre, axis=1) - radius) <= _CIRCLE_BAND_M]
    angles = np.arctan2(on[:, 1] - centre[1], on[:, 0] - centre[0])
    sectors = np.unique(np.floor((angles + np.pi) / (2 * np.pi) * 36).astype(int) % 36)
    covered = len(on) >= _MIN_RING_POINTS and len(sectors) >= _MIN_ARC_SHARE * 36
    return 2.0 * radius if covered else float("nan")


def _shrubs(
    rng: np.random.Generator,
    height: Callable[[np.ndarray], np.ndarray],
    clear_of: np.ndarray,
    options: PlotOptions,
) -> list[np.ndarray]:
    """Shrubs within 4 m beyond the plot, not on a stem foot or a tripod position."""
    parts = []
    for _ in range(options.shrubs):
        for _ in range(100):
            xy = _in_disc(rng, options.plot_radius_m + 4.0)
            if np.hypot(*(clear_of - xy).T).min() >= _STEM_CLEARANCE_M:
                parts.append(shrub(rng, xy, float(height(xy[None])[0])))
                break
    return parts


def plot_scene(
    trees: Sequence[Cloud], options: PlotOptions, seed: int = 0
) -> PlotScene:
    """Stand the trees on a plot with ground, shrubs and the tripod positions.

    Parameters
    ----------
    trees : sequence of Cloud
        Complete tree clouds (z up); ``options.trees`` of them are drawn (all: None).
    options : PlotOptions
    seed : int

    Returns
    -------
    PlotScene

    Raises
    ------
    InvalidInput
        Fewer trees than asked for (or than 3), or no room for the trees or the
        positions.
    """
    n = len(trees) if options.trees is None else options.trees
    if len(trees) < max(n, MIN_TREES):
        raise InvalidInput(
            f"A plot of {max(n, MIN_TREES)} trees needs as many tree clouds, got "
            f"{len(trees)}; give more (a file may be given twice)"
            + (
                " or place fewer."
                if n > MIN_TREES
                else f": a plot has {MIN_TREES} at least."
            )
        )
    rng = np.random.default_rng(seed)
    chosen = [trees[int(i)] for i in rng.permutation(len(trees))[:n]]
    feet = _place_feet(rng, n, options)
    positions = _place_positions(rng, feet, options)
    reach = options.plot_radius_m + options.range_m
    height = ground_height(rng, options.slope_deg, options.roughness_m, reach)
    if options.relief_m > 0:
        relief = np.random.default_rng([seed, RELIEF_STREAM])
        height = with_relief(height, relief, options.relief_m, reach)
    parts, placed = [], []
    for tree, xy in zip(chosen, feet, strict=True):
        heading, scale = rng.uniform(0.0, 2 * np.pi), rng.uniform(*options.scale)
        parts.append(standing(tree, xy, heading, height, scale))
        foot = np.r_[xy, height(xy[None])[0]]
        placed.append(_measure(tree.name, parts[-1], foot, rng))
    tree_of = [np.full(len(p), k, dtype=np.int64) for k, p in enumerate(parts)]
    parts += _shrubs(rng, height, np.vstack([feet, positions]), options)
    parts.append(ground_disc(rng, height, options.ground_spacing_m, reach))
    xyz = np.vstack(parts)
    tree_of.append(np.full(len(xyz) - sum(map(len, tree_of)), -1, dtype=np.int64))
    return PlotScene(
        Cloud(xyz, name="plot"),
        np.concatenate(tree_of),
        tuple(placed),
        np.column_stack([positions, height(positions)]),
    )


def _swayed(
    scene: PlotScene, rng: np.random.Generator, sway_m: tuple[float, float]
) -> np.ndarray:
    """Return the scene's points with every tree bent by the wind (feet stay put)."""
    xyz = np.array(scene.cloud.xyz)
    for k, tree in enumerate(scene.trees):
        mine = scene.tree_of == k
        top, a = rng.uniform(*sway_m), rng.uniform(0.0, 2 * np.pi)
        up = np.clip((xyz[mine, 2] - tree.foot[2]) / tree.height_m, 0.0, None)
        xyz[mine, :2] += top * up[:, None] ** 2 * np.array([np.cos(a), np.sin(a)])
    return xyz


def _scan_spec(
    rng: np.random.Generator, position: np.ndarray, res_deg: float, options: PlotOptions
) -> dict[str, float]:
    return {
        "azimuth_deg": float(np.degrees(np.arctan2(position[1], position[0]))),
        "distance_m": float(np.hypot(position[0], position[1])),
        "height_m": float(options.height_m),
        "res_deg": float(res_deg),
        "noise_m": float(options.noise_m),
        "heading_deg": float(rng.uniform(0.0, 360.0)),
        "tilt_deg": float(rng.uniform(0.0, options.tilt_deg)),
        "tilt_dir_deg": float(rng.uniform(0.0, 360.0)),
    }


def _scan(
    xyz: np.ndarray,
    radius: np.ndarray,
    pose: Transform,
    res_deg: float,
    noise_m: float,
    rng: np.random.Generator,
    *,
    reporter: Reporter = NULL_REPORTER,
) -> Cloud:
    """Scan the points ``xyz`` from ``pose``, one azimuth sector at a time.

    Each sector is scanned (:func:`amrst.simulate.simulate_scan`) with the points of
    a margin on both sides, every point whose disc can share a beam with one of its
    own, and keeps its own points. Each sector's beam grid is coarsened from its own
    points as :func:`amrst.simulate.visible_points` does (beams finer than a quarter
    of a disc change which edge points win a beam, not what is hidden).
    """
    from amrst.simulate.scanner import _CELLS_PER_RADIUS, _MAX_HALF_BINS

    local = apply_transform(invert_transform(pose), xyz)
    r = np.maximum(np.linalg.norm(local, axis=1), 1e-9)
    azimuth = np.arctan2(local[:, 1], local[:, 0]) + np.pi  # 0 .. 2 pi
    # A point's disc spans at most _MAX_HALF_BINS cells of the (possibly coarsened)
    # grid; two such discs meet within twice that. Doubled: a sector's grid may be
    # coarser than the whole scan's.
    cell = max(np.radians(res_deg), float(np.median(radius / r)) / _CELLS_PER_RADIUS)
    margin = 4 * (_MAX_HALF_BINS + 1) * cell
    width = 2 * np.pi / _SECTORS
    sector = np.minimum((azimuth / width).astype(np.int64), _SECTORS - 1)
    parts = []
    for j in range(_SECTORS):
        reporter.progress(j / _SECTORS)
        off = np.abs((azimuth - (j + 0.5) * width + np.pi) % (2 * np.pi) - np.pi)
        near = np.flatnonzero(off <= width / 2 + margin)
        scan, index = simulate_scan(
            Cloud(xyz[near]),
            pose,
            res_deg=res_deg,
            noise_m=noise_m,
            footprint_m=radius[near],
            rng=rng,
        )
        parts.append(scan.xyz[sector[near[index]] == j])
    return Cloud(np.vstack(parts))


def simulate_plot(
    trees: Sequence[Cloud],
    options: PlotOptions,
    *,
    seed: int = 0,
    reporter: Reporter = NULL_REPORTER,
) -> SimulatedPlot:
    """Scan a plot of ``trees`` from ``options.positions`` tripod positions.

    Parameters
    ----------
    trees : sequence of Cloud
        Complete tree clouds (z up), each named (the name goes into the truth).
    options : PlotOptions
    seed : int
        Seeds the plot and the scans: the same seed and trees give the same case.
    reporter : Reporter
        Told the progress scan by scan.

    Returns
    -------
    SimulatedPlot

    Raises
    ------
    InvalidInput
        As :func:`plot_scene`, a bad seed, a tree of under 100 points or 1 m, or a
        scan that keeps under 100 points.
    """
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
        raise InvalidInput(f"seed must be an integer of 0 or more, got {seed!r}.")
    for tree in trees:
        tall = float(np.ptp(tree.xyz[:, 2])) if len(tree) else 0.0
        if len(tree) < MIN_POINTS or tall < MIN_TREE_HEIGHT_M:
            raise InvalidInput(
                f"{tree.name or 'A tree'} has {len(tree)} point(s) over {tall:.2g} m "
                f"of height: a plot is made of complete tree clouds (at least "
                f"{MIN_POINTS} points, {MIN_TREE_HEIGHT_M:g} m tall)."
            )
    scene = plot_scene(trees, options, seed)
    rng = np.random.default_rng([int(seed), 1])  # the scans' own stream
    radius = footprints(scene.cloud.xyz)
    scans, poses, specs = [], [], []
    n = len(scene.positions)
    for k, position in enumerate(scene.positions):
        step = SubReporter(reporter, k / n, (k + 1) / n, f"scan {k + 1} of {n}")
        xyz = np.asarray(scene.cloud.xyz)
        if k and max(options.sway_m) > 0:
            xyz = _swayed(scene, rng, options.sway_m)
        res = options.res_deg * (2.0 if k and options.sparse else 1.0)
        spec = _scan_spec(rng, position, res, options)
        # The spec's azimuth and distance place the scanner over its own ground point.
        pose = scanner_pose(np.r_[0.0, 0.0, position[2]], spec)
        near = np.linalg.norm(xyz - pose[:3, 3], axis=1) <= options.range_m
        scan = _scan(
            xyz[near], radius[near], pose, res, options.noise_m, rng, reporter=step
        )
        scan = scan.select(np.linalg.norm(scan.xyz, axis=1) <= options.range_m)
        if len(scan) < MIN_POINTS:
            raise InvalidInput(
                f"Scan {k + 1} of the plot keeps only {len(scan)} point(s); at least "
                f"{MIN_POINTS} are needed: use a smaller res_deg or denser trees."
            )
        scans.append(Cloud(scan.xyz, name=f"scan_{k + 1}"))
        poses.append(pose)
        specs.append(spec)
    reporter.progress(1.0, "scans made")
    return SimulatedPlot(
        tuple(scans), tuple(poses), tuple(specs), scene.trees, options.kind
    )


def plot_truth(plot: SimulatedPlot, seed: int | None = None) -> dict[str, Any]:
    """Return the ``truth.json`` document of a simulated plot (the plot cases' keys).

    Stems are in scan 1's frame; a DBH that is NaN is written ``null`` (strict JSON).
    """
    onto_first = plot.T_scan1_scank()
    T_scan1_plot = invert_transform(plot.poses[0])
    feet = apply_transform(T_scan1_plot, np.array([t.foot for t in plot.trees]))
    doc: dict[str, Any] = {}
    if len(plot.scans) == 2:
        doc["T_target_source"] = onto_first[1].tolist()
    doc |= {
        "T_scan1_scank": [T.tolist() for T in onto_first],
        "spec_target": dict(plot.specs[0]),
        "spec_source": dict(plot.specs[1]),
        "specs": [dict(s) for s in plot.specs],
        "trees": [t.name for t in plot.trees],
        "stems_xy": [[round(float(c), 3) for c in t.foot[:2]] for t in plot.trees],
        "stems_target_frame": [
            {
                "tree": t.name,
                "x": round(float(f[0]), 4),
                "y": round(float(f[1]), 4),
                "z_base": round(float(f[2]), 4),
                "dbh_m": round(t.dbh_m, 4),
                "height_m": round(t.height_m, 3),
            }
            for t, f in zip(plot.trees, feet, strict=True)
        ],
        "kind": plot.kind,
        "seed": seed,
        "n_points": [len(s) for s in plot.scans],
        "what": "plot-level: several real trees, ground, shrubs, "
        f"{len(plot.scans)} scan positions inside the plot",
    }
    return doc


def write_plot_case(
    plot: SimulatedPlot, out_dir: str | os.PathLike[str], seed: int | None = None
) -> Path:
    """Write the scans and ``truth.json`` into a new or empty folder, as one unit.

    Returns
    -------
    Path
        The case folder.

    Raises
    ------
    InvalidInput
        As :func:`amrst.io.cases.check_case_folder`.
    """
    from amrst.files.atomic import make_folder, write_json_atomic
    from amrst.files.outdir import replace_files
    from amrst.io.cases import cloud_writer, plot_scan_names

    out = make_folder(check_case_folder(out_dir), "case folder")
    truth = plot_truth(plot, seed)
    writers: dict[str, Callable[[Path], object]] = {
        name: cloud_writer(cloud)
        for name, cloud in zip(
            plot_scan_names(len(plot.scans)), plot.scans, strict=True
        )
    }
    writers["truth.json"] = lambda p: write_json_atomic(p, truth, indent=1)
    replace_files(out, writers, managed=set(writers))
    return out
