"""A virtual tripod TLS scanner: two partial scans of one tree, with exact truth.

Each scan keeps what one scanner position could see. The scanner fires one beam per
cell of an azimuth/elevation grid (``res_deg`` wide); every tree point is a small disc
of radius ``footprint_m`` that covers all the grid cells within its angular radius
``footprint_m / range``, each cell keeps its nearest point, and a point survives when it
is the nearest one in at least one cell. By default each disc's radius is the distance
to the point's 4th nearest neighbour: discs that close the surface whether the cloud
was thinned to a regular spacing or sampled at random (with the median spacing,
random samples leave holes through which the far side of a trunk shows). Points
hidden behind nearer ones are dropped (occlusion shadows), and at long range several
points share a cell so fewer survive (density falls with range once the beam spacing
exceeds the tree's point spacing).
The survivors get Gaussian range noise along their beam and are written in the
scanner's own frame: scanner at the origin, random heading about z, small random tilt.

The truth ``T_target_source`` is the composition of the two exact scanner poses.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from amrst.errors import InvalidInput
from amrst.geometry import rotvec_matrix
from amrst.io.cases import check_case_folder, write_case
from amrst.simulate.scanner import footprints, visible_points
from amrst.simulate.settings import MAX_NOISE_M, MAX_TILT_DEG, check_settings
from amrst.types import (
    Cloud,
    Transform,
    apply_transform,
    invert_transform,
    make_transform,
)

# Fewest points a tree and each simulated scan must have.
MIN_POINTS = 100


@dataclass(frozen=True, eq=False)
class SimulatedPair:
    """Two simulated scans of one tree and the exact transform between them.

    Attributes
    ----------
    target, source : Cloud
        The scans, each in its own scanner frame (scanner at the origin, offset zero).
    T_target_source : (4, 4) float64
        Maps source-scanner coordinates into target-scanner coordinates (exact).
    spec_target, spec_source : dict
        How each scan was made: ``azimuth_deg``, ``distance_m``, ``height_m``,
        ``res_deg``, ``noise_m``, ``heading_deg``, ``tilt_deg``, ``tilt_dir_deg``.
    T_tree_target, T_tree_source : (4, 4) float64
        Scanner poses: map scanner coordinates into the tree's local coordinates.
    index_target, index_source : (N,) int64
        Index into the tree cloud of each kept point.
    """

    target: Cloud
    source: Cloud
    T_target_source: Transform
    spec_target: dict[str, float]
    spec_source: dict[str, float]
    T_tree_target: Transform
    T_tree_source: Transform
    index_target: np.ndarray
    index_source: np.ndarray

    @property
    def shared_fraction(self) -> float:
        """Tree points seen by both scans, over the points of the smaller scan."""
        both = np.intersect1d(self.index_target, self.index_source).size
        smaller = min(self.index_target.size, self.index_source.size)
        return float(both / smaller) if smaller else 0.0


#: The trunk's foot is the lowest point with this many points within this height
#: above it: fewer are strays below the tree.
_FOOT_POINTS = 20
_FOOT_BAND_M = 0.25


def trunk_base(xyz: np.ndarray) -> np.ndarray:
    """Where the trunk meets the ground: median xy of the lowest 0.5 m, lowest z.

    The lowest z is the lowest point that is no stray (``_FOOT_POINTS`` within
    ``_FOOT_BAND_M`` above it), not a height percentile: a sparse trunk under a dense
    crown holds fewer points than any small share of the cloud.

    Parameters
    ----------
    xyz : (N, 3) float64
        Tree points.

    Returns
    -------
    (3,) float64
    """
    z = np.sort(xyz[:, 2])
    above = np.searchsorted(z, z + _FOOT_BAND_M, side="right") - np.arange(len(z))
    z0 = float(z[int(np.argmax(above >= min(_FOOT_POINTS, len(z))))])
    low = xyz[(xyz[:, 2] >= z0) & (xyz[:, 2] < z0 + 0.5)]
    return np.array([np.median(low[:, 0]), np.median(low[:, 1]), z0])


def scanner_pose(base: np.ndarray, spec: dict[str, float]) -> Transform:
    """Return the pose ``T_tree_scanner`` of a scanner placed as ``spec`` says.

    The scanner stands ``distance_m`` from ``base`` in direction ``azimuth_deg``,
    ``height_m`` above it; its frame is turned by ``heading_deg`` about z and tipped by
    ``tilt_deg`` towards ``tilt_dir_deg``.

    Parameters
    ----------
    base : (3,) float64
        Trunk base in tree coordinates.
    spec : dict
        Keys ``azimuth_deg``, ``distance_m``, ``height_m``, ``heading_deg``,
        ``tilt_deg``, ``tilt_dir_deg``.

    Returns
    -------
    (4, 4) float64
        Maps scanner coordinates into tree coordinates.
    """
    az = np.radians(spec["azimuth_deg"])
    centre = base + np.array(
        [
            spec["distance_m"] * np.cos(az),
            spec["distance_m"] * np.sin(az),
            spec["height_m"],
        ]
    )
    d = np.radians(spec["tilt_dir_deg"])
    tilt_axis = np.array([-np.sin(d), np.cos(d), 0.0])  # horizontal, unit
    R_tilt = rotvec_matrix(tilt_axis * np.radians(spec["tilt_deg"]))
    R_head = rotvec_matrix(np.array([0.0, 0.0, np.radians(spec["heading_deg"])]))
    return make_transform(R_tilt @ R_head, centre)


def simulate_scan(
    tree: Cloud,
    T_tree_scanner: Transform,
    *,
    res_deg: float,
    noise_m: float,
    footprint_m: float | np.ndarray,
    rng: np.random.Generator,
) -> tuple[Cloud, np.ndarray]:
    """One scan of ``tree`` from the scanner pose ``T_tree_scanner``.

    Parameters
    ----------
    tree : Cloud
        The complete tree (local coordinates are used; the offset is ignored).
    T_tree_scanner : (4, 4) float64
        Scanner pose in tree coordinates.
    res_deg, noise_m : float
        Beam grid step (deg), range noise sigma (m).
    footprint_m : float or (N,) float64
        Disc radius of every tree point (m).
    rng : numpy.random.Generator
        Source of the range noise.

    Returns
    -------
    cloud : Cloud
        Kept points in the scanner frame, with their attributes.
    index : (K,) int64
        Index of each kept point in ``tree``.
    """
    local = apply_transform(invert_transform(T_tree_scanner), tree.xyz)
    index = visible_points(local, res_deg, footprint_m)
    kept = local[index]
    if noise_m > 0 and len(kept):
        r = np.linalg.norm(kept, axis=1)
        kept = kept * ((r + rng.normal(0.0, noise_m, len(r))) / r)[:, None]
    scan = tree.select(index)
    return Cloud(kept, np.zeros(3), scan.attributes, tree.name, {}), index


def simulate_pair(
    tree: Cloud,
    *,
    seed: int = 0,
    separation_deg: float = 90.0,
    distance_m: float | tuple[float, float] = 8.0,
    res_deg: float = 0.04,
    noise_m: float = 0.004,
    tilt_deg: float = 0.5,
    height_m: float = 1.5,
    footprint_m: float | np.ndarray | None = None,
    base: np.ndarray | None = None,
) -> SimulatedPair:
    """Two tripod scans of one tree from positions ``separation_deg`` apart around it.

    Parameters
    ----------
    tree : Cloud
        A complete tree cloud (z up), at least 100 points.
    seed : int
        Seeds the start azimuth, headings, tilts and noise.
    separation_deg : float
        Azimuth between the two scanner positions around the trunk base (deg).
    distance_m : float or (float, float)
        Horizontal distance from the trunk base to the target and source scanners (m).
    res_deg : float
        Angular step of the beam grid (deg).
    noise_m : float
        Standard deviation of the range noise (m).
    tilt_deg : float
        Largest residual tilt of each scanner (deg); drawn uniformly in [0, tilt_deg].
    height_m : float
        Scanner height above the trunk base (m).
    footprint_m : float or None
        Radius of the disc each tree point covers (m); None uses each point's distance
        to its 4th nearest neighbour (discs that close the surface: trunks cast
        shadows).
    base : (3,) float64 or None
        The point the scanners are placed around (default: :func:`trunk_base` of the
        cloud; a field scene gives its tree's stem foot, not the lowest ground point).

    Returns
    -------
    SimulatedPair

    Raises
    ------
    InvalidInput
        If the tree has fewer than 100 points, a parameter is not finite or out of
        range, or a scan keeps fewer than 100 points.
    """
    if len(tree) < MIN_POINTS:
        raise InvalidInput(
            f"The tree has {len(tree)} points; at least {MIN_POINTS} are needed."
        )
    # A number or a pair (np.isscalar narrows to numpy's scalar types, not to float).
    pair: Any = (distance_m, distance_m) if np.isscalar(distance_m) else distance_m
    distances: tuple[float, ...] = tuple(pair)
    if len(distances) != 2:
        raise InvalidInput("distance_m must be one positive number or two.")
    check_settings(
        seed=seed,
        separation_deg=separation_deg,
        distance_m=distances,
        res_deg=res_deg,
        noise_m=noise_m,
        tilt_deg=tilt_deg,
        height_m=height_m,
    )
    if footprint_m is not None and not np.all(np.isfinite(footprint_m)):
        raise InvalidInput("footprint_m must be finite (not NaN or infinity).")
    if footprint_m is None:
        footprint_m = footprints(tree.xyz)
    rng = np.random.default_rng(seed)
    base = trunk_base(tree.xyz) if base is None else np.asarray(base, dtype=float)
    start = float(rng.uniform(-180.0, 180.0))
    specs, poses, scans, indices = [], [], [], []
    for k, dist in enumerate(distances):
        azimuth = (start + k * separation_deg + 180.0) % 360.0 - 180.0
        spec = {
            "azimuth_deg": azimuth,
            "distance_m": float(dist),
            "height_m": float(height_m),
            "res_deg": float(res_deg),
            "noise_m": float(noise_m),
            "heading_deg": float(rng.uniform(0.0, 360.0)),
            "tilt_deg": float(rng.uniform(0.0, tilt_deg)),
            "tilt_dir_deg": float(rng.uniform(0.0, 360.0)),
        }
        pose = scanner_pose(base, spec)
        scan, index = simulate_scan(
            tree,
            pose,
            res_deg=res_deg,
            noise_m=noise_m,
            footprint_m=footprint_m,
            rng=rng,
        )
        if len(scan) < MIN_POINTS:
            role = "target" if k == 0 else "source"
            raise InvalidInput(
                f"The simulated {role} scan of {tree.name or 'the tree'} keeps only "
                f"{len(scan)} point(s); at least {MIN_POINTS} are needed. The tree "
                f"cloud has too few distinct points ({len(tree)} points, "
                f"{_distinct(tree.xyz)} distinct) or the scanner is too far or too "
                "coarse: use a denser tree cloud, a smaller res_deg or a shorter "
                "distance_m."
            )
        specs.append(spec)
        poses.append(pose)
        scans.append(scan)
        indices.append(index)
    return SimulatedPair(
        target=scans[0],
        source=scans[1],
        T_target_source=invert_transform(poses[0]) @ poses[1],
        spec_target=specs[0],
        spec_source=specs[1],
        T_tree_target=poses[0],
        T_tree_source=poses[1],
        index_target=indices[0],
        index_source=indices[1],
    )


def _distinct(xyz: np.ndarray) -> int:
    """Count the distinct points of a cloud (exact coordinates)."""
    return len(np.unique(np.asarray(xyz), axis=0)) if len(xyz) else 0


__all__ = [
    "MAX_NOISE_M",
    "MAX_TILT_DEG",
    "MIN_POINTS",
    "SimulatedPair",
    "check_case_folder",
    "check_settings",
    "footprints",
    "scanner_pose",
    "simulate_pair",
    "simulate_scan",
    "trunk_base",
    "visible_points",
    "write_case",
]
