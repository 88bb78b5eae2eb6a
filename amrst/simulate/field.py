"""Field-like scenes for the virtual scanner: ground, neighbour trees, shrubs, a clip.

A technician's scan of a tree also holds the ground, parts of the neighbouring trees
(which hide parts of the tree) and understory, and is cut out with a vertical cylinder
around the stem. :func:`field_scene` builds such a scene around one tree:

- a rough, gently sloped ground disc (a plane of random slope up to ``slope_deg``
  plus smooth bumps of about ``roughness_m``), sampled every ``ground_spacing_m``;
- the tree with its stem foot on the ground at the origin;
- each neighbour tree turned to a random heading, its foot on the ground
  ``neighbour_distance_m`` away in a random direction;
- ``shrubs`` leafy blobs 0.3-1.2 m tall.

:func:`simulate_field_pair` scans it from two tripod positions (``amrst.simulate``)
and clips both scans with a cylinder of ``clip_radius_m`` around the stem.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import TYPE_CHECKING, Any

import numpy as np

from amrst.errors import InvalidInput
from amrst.geometry import yaw_rotation
from amrst.simulate import SimulatedPair, simulate_pair, trunk_base
from amrst.simulate.settings import check_numbers
from amrst.types import Cloud, apply_transform

if TYPE_CHECKING:
    from collections.abc import Callable

TREE, GROUND, OTHER = 0, 1, 2  # scene labels, as amrst.stages.scene numbers them


@dataclass(frozen=True, slots=True, kw_only=True)
class FieldOptions:
    """What the field scene holds around the tree.

    ground : bool
        Add the ground disc.
    ground_spacing_m, slope_deg, roughness_m : float
        Ground point spacing, largest slope (drawn uniformly up to it), bump height.
    neighbours : tuple of Cloud
        Other complete trees to stand around the tree.
    neighbour_distance_m : (float, float)
        Range of stem-to-stem distances of the neighbours.
    shrubs : int
        Number of shrubs.
    clip_radius_m : float or None
        Radius of the cylinder cut around the stem (None: no cut).
    """

    ground: bool = True
    ground_spacing_m: float = 0.05
    slope_deg: float = 8.0
    roughness_m: float = 0.04
    neighbours: tuple[Cloud, ...] = ()
    neighbour_distance_m: tuple[float, float] = (2.5, 6.0)
    shrubs: int = 3
    clip_radius_m: float | None = 4.0

    def __post_init__(self) -> None:
        lo, hi = self.neighbour_distance_m
        if not (0 < lo <= hi):
            raise InvalidInput(
                f"neighbour distances must be 0 < min <= max, got {lo} and {hi}."
            )
        if not self.ground_spacing_m > 0:
            raise InvalidInput(
                f"ground spacing must be > 0, got {self.ground_spacing_m}."
            )
        check_numbers(
            {
                "slope_deg": self.slope_deg,
                "shrubs": self.shrubs,
                "clip_radius_m": self.clip_radius_m,
            },
            optional=True,  # no clip radius: the whole scene
        )


@dataclass(frozen=True, slots=True)
class FieldScene:
    """A scene cloud, each point's label, and the stem foot of the tree of interest."""

    cloud: Cloud
    labels: np.ndarray  # (N,) int8: TREE, GROUND or OTHER
    base: np.ndarray  # (3,) stem foot of the tree, on the ground, at the xy origin


def ground_height(
    rng: np.random.Generator,
    slope_deg: float,
    roughness_m: float,
    extent_m: float = 15.0,
) -> Callable[[np.ndarray], np.ndarray]:
    """Return a random ground: a plane of slope up to ``slope_deg`` plus smooth bumps.

    Bumps of about ``roughness_m`` are centred within ``extent_m`` of the origin (40
    of them in 15 m, as many per square metre beyond).

    Returns
    -------
    callable
        Maps (M, 2) xy to (M,) ground heights.
    """
    slope = np.tan(np.radians(rng.uniform(0.0, slope_deg)))
    direction = rng.uniform(0.0, 2 * np.pi)
    gx, gy = slope * np.cos(direction), slope * np.sin(direction)
    bumps = [
        (
            rng.uniform(-extent_m, extent_m, 2),
            rng.uniform(0.5, 2.0),
            rng.normal(0.0, 1.0),
        )
        for _ in range(round(40 * (extent_m / 15.0) ** 2))
    ]

    def height(xy: np.ndarray) -> np.ndarray:
        z = gx * xy[:, 0] + gy * xy[:, 1]
        for centre, width, amp in bumps:
            d2 = np.sum((xy - centre) ** 2, axis=1)
            z = z + roughness_m * amp * np.exp(-d2 / (2 * width**2))
        return np.asarray(z)

    return height


def with_relief(
    height: Callable[[np.ndarray], np.ndarray],
    rng: np.random.Generator,
    relief_m: float,
    extent_m: float,
) -> Callable[[np.ndarray], np.ndarray]:
    """Return ``height`` with hills and hollows of about ``relief_m``, 5-15 m across.

    Six are centred within 15 m of the origin, as many per square metre beyond, out
    to ``extent_m``: over a plot the terrain bends away from any plane by about
    ``relief_m``.
    """
    hills = [
        (
            rng.uniform(-extent_m, extent_m, 2),
            rng.uniform(2.5, 7.5),
            rng.normal(0.0, 1.0),
        )
        for _ in range(max(1, round(6 * (extent_m / 15.0) ** 2)))
    ]

    def relief(xy: np.ndarray) -> np.ndarray:
        z = height(xy)
        for centre, width, amp in hills:
            d2 = np.sum((xy - centre) ** 2, axis=1)
            z = z + relief_m * amp * np.exp(-d2 / (2 * width**2))
        return np.asarray(z)

    return relief


def standing(
    tree: Cloud,
    at_xy: np.ndarray,
    heading: float,
    height: Callable[[np.ndarray], np.ndarray],
    scale: float = 1.0,
) -> np.ndarray:
    """Tree points turned by ``heading`` and scaled about its foot, the foot on the ground.

    Returns
    -------
    (N, 3) float64
    """
    xyz = np.asarray(tree.xyz, dtype=float)
    foot = trunk_base(xyz)
    local = (xyz - foot) @ yaw_rotation(heading).T * scale
    z0 = float(height(at_xy[None])[0])
    # Sink the foot 5 cm: the stem enters the ground instead of floating over bumps.
    return np.asarray(local + np.r_[at_xy, z0 - 0.05])


def shrub(rng: np.random.Generator, at_xy: np.ndarray, z0: float) -> np.ndarray:
    """Return a leafy blob 0.3-1.2 m tall standing at ``at_xy`` on the height ``z0``."""
    h = rng.uniform(0.3, 1.2)
    r = rng.uniform(0.3, 0.8) * max(h, 0.5)
    n = int(600 * r * h + 100)
    d = rng.normal(size=(n, 3))
    d /= np.linalg.norm(d, axis=1)[:, None]
    shell = d * (rng.uniform(0.6, 1.0, n) ** (1 / 3))[:, None]
    pts = shell * np.array([r, r, h / 2]) + np.r_[at_xy, z0 + h / 2]
    return np.asarray(pts)


def ground_disc(
    rng: np.random.Generator,
    height: Callable[[np.ndarray], np.ndarray],
    spacing_m: float,
    reach_m: float,
) -> np.ndarray:
    """Ground points every ``spacing_m`` (jittered) within ``reach_m`` of the origin.

    Returns
    -------
    (M, 3) float64
    """
    axis = np.arange(-reach_m, reach_m + spacing_m / 2, spacing_m)
    gx, gy = np.meshgrid(axis, axis)
    xy = np.column_stack([gx.ravel(), gy.ravel()])
    xy = xy[np.hypot(xy[:, 0], xy[:, 1]) <= reach_m]
    jitter = spacing_m / 3
    xy = xy + rng.uniform(-jitter, jitter, xy.shape)  # no regular lattice
    return np.column_stack([xy, height(xy)])


def field_scene(tree: Cloud, options: FieldOptions, seed: int = 0) -> FieldScene:
    """Build the scene: ground disc, the tree at the origin, neighbours, shrubs.

    Parameters
    ----------
    tree : Cloud
        The tree of interest (complete, z up).
    options : FieldOptions
    seed : int

    Returns
    -------
    FieldScene
    """
    rng = np.random.default_rng(seed + 7919)
    height = ground_height(rng, options.slope_deg, options.roughness_m)
    parts = [standing(tree, np.zeros(2), 0.0, height)]
    labels = [np.full(len(parts[0]), TREE, dtype=np.int8)]
    for other in options.neighbours:
        az = rng.uniform(0.0, 2 * np.pi)
        dist = rng.uniform(*options.neighbour_distance_m)
        xy = dist * np.array([np.cos(az), np.sin(az)])
        parts.append(standing(other, xy, rng.uniform(0.0, 2 * np.pi), height))
        labels.append(np.full(len(parts[-1]), OTHER, dtype=np.int8))
    reach = (options.clip_radius_m or 12.0) + 1.0
    for _ in range(options.shrubs):
        xy = rng.uniform(0.8, reach - 0.5) * np.array(
            (lambda a: (np.cos(a), np.sin(a)))(rng.uniform(0.0, 2 * np.pi))
        )
        parts.append(shrub(rng, xy, float(height(xy[None])[0])))
        labels.append(np.full(len(parts[-1]), OTHER, dtype=np.int8))
    if options.ground:
        parts.append(ground_disc(rng, height, options.ground_spacing_m, reach))
        labels.append(np.full(len(parts[-1]), GROUND, dtype=np.int8))
    xyz = np.vstack(parts)
    base = np.array([0.0, 0.0, float(height(np.zeros((1, 2)))[0])])
    return FieldScene(Cloud(xyz, name=tree.name), np.concatenate(labels), base)


def simulate_field_pair(
    tree: Cloud, options: FieldOptions, *, seed: int = 0, **scan: Any
) -> tuple[SimulatedPair, dict[str, Any]]:
    """Two tripod scans of a field scene around ``tree``, clipped around its stem.

    Parameters
    ----------
    tree : Cloud
    options : FieldOptions
    seed : int
        Seeds the scene and the scans.
    **scan
        Passed on to :func:`amrst.simulate.simulate_pair` (separation_deg,
        distance_m, res_deg, noise_m, tilt_deg, height_m).

    Returns
    -------
    pair : SimulatedPair
        Indices refer to the scene's points.
    info : dict
        ``clip_radius_m`` and the points of each label in each scan, for truth.json.

    Raises
    ------
    InvalidInput
        As simulate_pair, or when a clipped scan keeps fewer than 100 points.
    """
    scene = field_scene(tree, options, seed)
    pair = simulate_pair(scene.cloud, seed=seed, base=scene.base, **scan)
    kept = {}
    for role in ("target", "source"):
        cloud = getattr(pair, role)
        index = getattr(pair, f"index_{role}")
        keep = np.ones(len(cloud), dtype=bool)
        if options.clip_radius_m is not None:
            # The cut is vertical in the scene (the scanners' residual tilt is small).
            in_scene = apply_transform(getattr(pair, f"T_tree_{role}"), cloud.xyz)
            keep = np.hypot(in_scene[:, 0], in_scene[:, 1]) <= options.clip_radius_m
        if keep.sum() < 100:
            raise InvalidInput(
                f"The clipped {role} scan keeps {int(keep.sum())} points; use a larger "
                "clip radius or a closer scanner."
            )
        kept[role] = (cloud.select(np.flatnonzero(keep)), index[keep])
    pair = replace(
        pair,
        target=kept["target"][0],
        source=kept["source"][0],
        index_target=kept["target"][1],
        index_source=kept["source"][1],
    )
    names = ("tree", "ground", "other")
    info: dict[str, Any] = {
        "clip_radius_m": options.clip_radius_m,
        "kind": "field-like: ground, neighbours, shrubs, clipped around the stem",
        "neighbours": [c.name for c in options.neighbours],
        "shrubs": options.shrubs,
        "labels_target": {
            n: int(np.sum(scene.labels[pair.index_target] == k))
            for k, n in enumerate(names)
        },
        "labels_source": {
            n: int(np.sum(scene.labels[pair.index_source] == k))
            for k, n in enumerate(names)
        },
    }
    return pair, info
