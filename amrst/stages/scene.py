"""Scene understanding: ground, the tree of interest, and everything else.

Scans from the field hold more than the tree: the ground, parts of neighbouring trees
and shrubs, cut out with a cylinder around the stem. Before the tree stages run, this
stage labels each point:

1. ``GROUND``: points within ``ground_dist_m`` of the ground surface (``ground.py``:
   a levelled plane under the lowest points plus relief). No ground is declared on a
   clean, segmented tree, and then nothing else changes (every point is ``TREE``).
2. Stems: connected clusters in a slice ``stem_low_m``..``stem_high_m`` above the
   ground that span the slice's height and are narrower than ``stem_max_width_m``
   (shrubs are lower, crowns wider); centre and radius from a circle fit.
3. The tree of interest: the stem nearest the clip axis (the centre of the scan's
   footprint, as a cylinder cut leaves it) or nearest a position the user gives.
4. ``TREE`` / ``OTHER``: every point above the ground goes to the stem it reaches by
   the shortest path through neighbouring points (links up to ``link_m``); pieces
   that reach no stem are ``OTHER`` when low (shrubs) and go with the nearest labelled
   point when high (crown parts cut off by occlusion).

The tree base is where the chosen stem meets the ground surface, not the lowest point
of the file.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import TYPE_CHECKING

import numpy as np

from amrst.stages.ground import fit_ground
from amrst.stages.stems import Stem, assign_to_stems, find_stems
from amrst.stages.voxels import finite_rows

if TYPE_CHECKING:
    from collections.abc import Iterable, Sequence

TREE, GROUND, OTHER, OUTSIDE = 0, 1, 2, 3
LABEL_NAMES = ("tree", "ground", "other", "outside")
SCENE_MODES = ("auto", "off")
SCENE_POINTS = ("above_ground", "tree")
MAX_GROUND_POINTS = 500_000
#: A scan holding this many stems or more is a plot's, not one tree's (the field scene
#: of one tree with its neighbours holds fewer): ``amrst plot`` lists its trees.
PLOT_STEMS = 5
# Two levelled scanners (residual tilt up to 2 deg each) see one ground tilted by at
# most 4 deg apart; a little more for the fit.
TILT_MARGIN_DEG = 5.0


@dataclass(frozen=True, slots=True, kw_only=True)
class SceneParams:
    """Ground, stems and the tree of interest."""

    mode: str = field(
        default="auto",
        metadata={
            "choices": SCENE_MODES,
            "help": "auto: find ground and neighbours when the scan has a ground (a clean tree is left as it is); off: treat every point as the tree.",
        },
    )
    use_points: str = field(
        default="above_ground",
        metadata={
            "choices": SCENE_POINTS,
            "help": "Points the tree stages get: above_ground (tree, neighbours and shrubs: the whole scene is rigid, so neighbours are extra anchors) or tree (the tree of interest alone).",
        },
    )
    cell_m: float = field(
        default=0.5,
        metadata={
            "unit": "m",
            "min": 0.05,
            "max": 5.0,
            "help": "Grid cell of the ground fit.",
        },
    )
    ground_tol_m: float = field(
        default=0.15,
        metadata={
            "unit": "m",
            "min": 0.01,
            "max": 2.0,
            "help": "A cell's lowest point within this of the plane is on the ground.",
        },
    )
    ground_dist_m: float = field(
        default=0.15,
        metadata={
            "unit": "m",
            "min": 0.0,
            "max": 2.0,
            "help": "Points less than this above the ground surface are ground.",
        },
    )
    max_slope_deg: int = field(
        default=20,
        metadata={
            "unit": "deg",
            "min": 0,
            "max": 60,
            "help": "Steepest ground considered (whole degrees).",
        },
    )
    min_ground_area_m2: float = field(
        default=12.0,
        metadata={
            "unit": "m²",
            "min": 0.0,
            "max": 1e6,
            "help": "Ground area a scan must show to have a ground (clean trees: at most 7.5 m² of stem foot on a plane).",
        },
    )
    expected_ground_area_m2: float = field(
        default=4.0,
        metadata={
            "unit": "m²",
            "min": 0.0,
            "max": 1e6,
            "help": "The same test when the other scan of the pair has a ground (a scan whose ground is hidden by undergrowth can show a few m² plane on shrub bases, which is not a ground).",
        },
    )
    stem_low_m: float = field(
        default=0.3,
        metadata={
            "unit": "m",
            "min": 0.0,
            "max": 5.0,
            "help": "Bottom of the stem slice above the ground.",
        },
    )
    stem_high_m: float = field(
        default=1.5,
        metadata={
            "unit": "m",
            "min": 0.1,
            "max": 10.0,
            "help": "Top of the stem slice above the ground (shrubs lower than this are not stems).",
        },
    )
    stem_max_width_m: float = field(
        default=2.5,
        metadata={
            "unit": "m",
            "min": 0.05,
            "max": 10.0,
            "help": "Widest stem cluster in the slice (buttresses included).",
        },
    )
    link_m: float = field(
        default=0.15,
        metadata={
            "unit": "m",
            "min": 0.01,
            "max": 2.0,
            "help": "Longest link between neighbouring points when clusters and paths are traced.",
        },
    )
    crown_height_m: float = field(
        default=1.5,
        metadata={
            "unit": "m",
            "min": 0.0,
            "max": 20.0,
            "help": "A piece that reaches no stem goes with its nearest labelled neighbour when higher than this; lower, it is a shrub (other).",
        },
    )
    crop_radius_m: float = field(
        default=6.0,
        metadata={
            "unit": "m",
            "min": 0.0,
            "max": 1000.0,
            "help": "With a stem position given (--stem): points farther than this from it are left out, as a technician's cylinder cut would (a whole plot scan becomes a field scan of one tree); 0 = keep all.",
        },
    )
    seed: int = field(
        default=0, metadata={"min": 0, "help": "Seed of the ground RANSAC."}
    )

    def __post_init__(self) -> None:
        if self.mode not in SCENE_MODES:
            raise ValueError(f"scene mode must be one of {SCENE_MODES}")
        if self.use_points not in SCENE_POINTS:
            raise ValueError(f"scene.use_points must be one of {SCENE_POINTS}")
        if self.stem_low_m >= self.stem_high_m:
            raise ValueError(
                f"scene.stem_low_m ({self.stem_low_m} m) must be below "
                f"scene.stem_high_m ({self.stem_high_m} m)"
            )


@dataclass(frozen=True, slots=True)
class SceneResult:
    """Per-point labels and what the scene holds."""

    labels: np.ndarray  # (N,) int8: TREE, GROUND or OTHER
    height_m: (
        np.ndarray
    )  # (N,) height above the ground surface (above the lowest point without ground)
    has_ground: bool
    ground_tilt_deg: float  # plane normal against the scan's z axis
    stems: tuple[Stem, ...]  # nearest the clip axis (or the given stem) first
    tree_stem: int  # index of the tree of interest in stems; -1 when none
    base: np.ndarray | None  # (3,) where the tree's stem meets the ground
    message: str

    def keep(self, use_points: str = "above_ground") -> np.ndarray:
        """(N,) bool: the points the tree stages get (see ``SceneParams.use_points``)."""
        if use_points == "tree" and self.has_ground:
            return np.asarray(self.labels == TREE)
        return np.asarray((self.labels == TREE) | (self.labels == OTHER))

    def counts(self) -> dict[str, int]:
        """Points per label name."""
        return {n: int(np.sum(self.labels == k)) for k, n in enumerate(LABEL_NAMES)}


def stem_counts(scenes: Iterable[SceneResult | None]) -> tuple[int, ...]:
    """Count the stems each scene holds (0 where the scene stage did not run)."""
    return tuple(0 if s is None else len(s.stems) for s in scenes)


def plot_stems(counts: Sequence[int]) -> tuple[int, ...] | None:
    """Return the scans' stem counts when one holds a plot's, else None.

    A plot's: ``PLOT_STEMS`` or more. A registration of such scans measures one stem
    of many.
    """
    return tuple(counts) if max(counts, default=0) >= PLOT_STEMS else None


def understand_scene(
    xyz: np.ndarray,
    params: SceneParams,
    stem_xy: np.ndarray | None = None,
    expect_ground: float | None = None,
    ground_xyz: np.ndarray | None = None,
) -> SceneResult:
    """Label ground, the tree of interest and other points of one scan.

    Parameters
    ----------
    xyz : (N, 3) float64
        Preprocessed points, local frame.
    params : SceneParams
    stem_xy : (2,) float64 or None
        A stem position the user gives (local frame); default: the footprint centre.
        Points farther than ``crop_radius_m`` from it are labelled ``OUTSIDE``.
    expect_ground : float or None
        The ground tilt (deg) of the other scan of the pair when it has a ground: then
        ``expected_ground_area_m2`` is enough, and the plane may tilt at most
        ``tilt_margin_deg`` more than that one (both scanners are about level).
    ground_xyz : (M, 3) float64 or None
        Points to fit the ground on, same frame (default ``xyz``): the scan before its
        outlier filter, which removes much of the sparse far ground. At most
        ``MAX_GROUND_POINTS`` of them are used (an even stride).

    Returns
    -------
    SceneResult
        Every point ``TREE`` when ``mode`` is off or no ground is found.
    """
    xyz = np.asarray(xyz, dtype=float)
    n = len(xyz)
    axis = (
        np.asarray(stem_xy, dtype=float).reshape(2)
        if stem_xy is not None
        else np.array([(xyz[:, d].min() + xyz[:, d].max()) / 2 for d in (0, 1)])
        if n
        else np.zeros(2)
    )
    labels = np.full(n, TREE, dtype=np.int8)
    if params.mode == "off" or n < 10:
        return _no_ground(labels, xyz, "scene analysis off")
    if stem_xy is not None and params.crop_radius_m > 0:
        # A whole plot scan with the stem given: cut it as a technician would.
        outside = np.hypot(*(xyz[:, :2] - axis).T) > params.crop_radius_m
        if (~outside).sum() >= 10:
            inner = understand_scene(
                xyz[~outside],
                replace(params, crop_radius_m=0.0),
                stem_xy,
                expect_ground,
                None
                if ground_xyz is None
                else _near(ground_xyz, axis, params.crop_radius_m),
            )
            labels[:] = OUTSIDE
            labels[~outside] = inner.labels
            height = np.full(n, np.nan)
            height[~outside] = inner.height_m
            return replace(
                inner,
                labels=labels,
                height_m=height,
                message=f"{inner.message}; {int(outside.sum())} points farther than "
                f"{params.crop_radius_m:g} m from the given stem left out",
            )
    gxyz = xyz if ground_xyz is None else np.asarray(ground_xyz, dtype=float)
    if not np.isfinite(gxyz).all():  # one pass; the rows only when needed
        gxyz = gxyz[finite_rows(gxyz)]
    if len(gxyz) > MAX_GROUND_POINTS:
        gxyz = gxyz[:: int(np.ceil(len(gxyz) / MAX_GROUND_POINTS))]
    ground = fit_ground(
        gxyz,
        cell_m=params.cell_m,
        tol_m=params.ground_tol_m,
        max_slope_deg=(
            params.max_slope_deg
            if expect_ground is None
            else min(params.max_slope_deg, expect_ground + TILT_MARGIN_DEG)
        ),
        min_area_m2=(
            params.min_ground_area_m2
            if expect_ground is None
            else params.expected_ground_area_m2
        ),
        iterations=300,
        seed=params.seed,
    )
    if not ground.found:
        return _no_ground(
            labels,
            xyz,
            f"no ground ({ground.area_m2:.1f} m² on a plane under the lowest points): "
            "treated as a segmented tree",
        )
    h = ground.height(xyz)
    labels[h < params.ground_dist_m] = GROUND
    above = np.flatnonzero(labels != GROUND)
    stems, slice_labels, slice_idx = find_stems(xyz, h, above, params)
    order = sorted(
        range(len(stems)), key=lambda k: float(np.linalg.norm(stems[k].xy - axis))
    )
    stems = [stems[k] for k in order]
    seeds = [slice_idx[slice_labels == k] for k in order]
    tree_stem = 0 if stems else -1
    if stems:
        owner = assign_to_stems(xyz, h, above, seeds, params)
        labels[above[owner != 0]] = OTHER
        base_xy = stems[0].xy
        base = np.r_[base_xy, ground.surface_z(base_xy)]  # where it meets the ground
    else:
        base = None
    counts = {nm: int(np.sum(labels == k)) for k, nm in enumerate(LABEL_NAMES)}
    msg = (
        f"ground {ground.area_m2:.0f} m² (tilt {ground.tilt_deg:.1f}°), "
        f"{len(stems)} stem(s); points: {counts['tree']} tree, {counts['ground']} ground, "
        f"{counts['other']} other"
    )
    return SceneResult(
        labels,
        h,
        True,
        ground.tilt_deg,
        tuple(stems),
        tree_stem,
        base,
        msg,
    )


def _near(xyz: np.ndarray, xy: np.ndarray, radius: float) -> np.ndarray:
    xyz = np.asarray(xyz, dtype=float)
    return np.asarray(xyz[np.hypot(xyz[:, 0] - xy[0], xyz[:, 1] - xy[1]) <= radius])


def _no_ground(labels: np.ndarray, xyz: np.ndarray, msg: str) -> SceneResult:
    z0 = float(xyz[:, 2].min()) if len(xyz) else 0.0
    return SceneResult(
        labels,
        xyz[:, 2] - z0,
        False,
        0.0,
        (),
        -1,
        None,
        msg,
    )
