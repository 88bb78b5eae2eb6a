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

import math
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any, cast

import numpy as np

from amrst.errors import InvalidInput
from amrst.io.cases import check_case_folder, write_case
from amrst.types import (
    Cloud,
    Transform,
    apply_transform,
    invert_transform,
    make_transform,
)

if TYPE_CHECKING:
    import argparse

# A point's footprint covers at most (2 * _MAX_HALF_BINS + 1)^2 grid cells; this bounds
# memory for points very close to the scanner or near the zenith.
_MAX_HALF_BINS = 12
# The grid is coarsened until a typical disc spans this many cells in radius.
_CELLS_PER_RADIUS = 4.0
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


def _rotation(axis: np.ndarray, angle_rad: float) -> np.ndarray:
    """(3, 3) rotation about a unit axis (Rodrigues)."""
    x, y, z = axis / np.linalg.norm(axis)
    K = np.array([[0.0, -z, y], [z, 0.0, -x], [-y, x, 0.0]])
    return cast(
        "np.ndarray",
        np.eye(3) + np.sin(angle_rad) * K + (1.0 - np.cos(angle_rad)) * (K @ K),
    )


def trunk_base(xyz: np.ndarray) -> np.ndarray:
    """Where the trunk meets the ground: median xy of the lowest 0.5 m, lowest z.

    Parameters
    ----------
    xyz : (N, 3) float64
        Tree points.

    Returns
    -------
    (3,) float64
    """
    z0 = float(np.percentile(xyz[:, 2], 0.5))
    low = xyz[xyz[:, 2] < z0 + 0.5]
    return np.array([np.median(low[:, 0]), np.median(low[:, 1]), z0])


def footprints(xyz: np.ndarray, k: int = 4) -> np.ndarray:
    """Per-point disc radius: the distance to the k-th nearest neighbour (m).

    Capped at three times the median so that isolated points do not hide whole regions.

    Parameters
    ----------
    xyz : (N, 3) float64
    k : int

    Returns
    -------
    (N,) float64
    """
    from scipy.spatial import cKDTree

    d = cKDTree(xyz).query(xyz, k=k + 1)[0][:, -1]
    return cast("np.ndarray", np.minimum(d, 3.0 * float(np.median(d))))


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
    R_tilt = _rotation(
        np.array([-np.sin(d), np.cos(d), 0.0]), np.radians(spec["tilt_deg"])
    )
    R_head = _rotation(np.array([0.0, 0.0, 1.0]), np.radians(spec["heading_deg"]))
    return make_transform(R_tilt @ R_head, centre)


def visible_points(
    xyz: np.ndarray, res_deg: float, footprint_m: float | np.ndarray
) -> np.ndarray:
    """Return indices of the points a scanner at the origin records (nearest per beam).

    Parameters
    ----------
    xyz : (N, 3) float64
        Points in the scanner frame.
    res_deg : float
        Angular step of the beam grid in azimuth and elevation (deg).
    footprint_m : float or (N,) float64
        Radius of the disc each point stands for (m).

    Returns
    -------
    (K,) int64
        Sorted indices of the points that are nearest in at least one grid cell.
    """
    r = np.linalg.norm(xyz, axis=1)
    idx = np.flatnonzero(r > 0.05)
    p, r = xyz[idx], r[idx]
    radius = np.broadcast_to(np.asarray(footprint_m, dtype=float), (len(xyz),))[idx]
    # Beams finer than a quarter of the typical disc change nothing but the cost: every
    # visible point already wins cells; so the grid is only as fine as that.
    typical = float(np.median(radius / r)) if len(r) else 0.0
    res = max(np.radians(res_deg), typical / _CELLS_PER_RADIUS)
    n_az = int(np.ceil(2 * np.pi / res))
    el = np.arcsin(np.clip(p[:, 2] / r, -1.0, 1.0))
    fa = (np.arctan2(p[:, 1], p[:, 0]) + np.pi) / res  # fractional cell coordinates
    fe = (el + np.pi / 2) / res
    ke = np.maximum(radius / r / res, 1e-9)  # angular radius in cells
    ka = ke / np.maximum(np.cos(el), 1e-3)  # an azimuth step shrinks towards the zenith
    na = np.minimum(np.ceil(ka), _MAX_HALF_BINS).astype(np.int64)
    ne = np.minimum(np.ceil(ke), _MAX_HALF_BINS).astype(np.int64)
    # Expand every point into its (2na+1) x (2ne+1) block of candidate cells.
    width = 2 * na + 1
    counts = width * (2 * ne + 1)
    pid = np.repeat(np.arange(len(p)), counts)
    k = np.arange(counts.sum()) - np.repeat(np.cumsum(counts) - counts, counts)
    da = k % width[pid] - na[pid]
    de = k // width[pid] - ne[pid]
    ia = np.floor(fa).astype(np.int64)[pid] + da
    ie = np.floor(fe).astype(np.int64)[pid] + de
    # Keep the cells whose centre lies inside the point's disc, and always its own cell.
    u = (ia + 0.5 - fa[pid]) / ka[pid]
    v = (ie + 0.5 - fe[pid]) / ke[pid]
    keep = (u * u + v * v <= 1.0) | ((da == 0) & (de == 0))
    pid, ia, ie = pid[keep], ia[keep], ie[keep]
    cell = (ie * n_az + np.mod(ia, n_az)).astype(np.int64)
    # One sort on (cell, range in 0.1 mm): each cell's first entry is its nearest point.
    r_q = np.minimum(np.round(r[pid] * 1e4), 2**24 - 1).astype(np.int64)
    order = np.argsort(cell * 2**24 + r_q, kind="stable")
    cell_sorted = cell[order]
    first = np.ones(len(order), dtype=bool)
    first[1:] = cell_sorted[1:] != cell_sorted[:-1]
    return cast("np.ndarray", idx[np.unique(pid[order[first]])])


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
    base = trunk_base(tree.xyz)
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


MAX_NOISE_M = 0.5
MAX_TILT_DEG = 45.0


def check_settings(
    *,
    seed: Any,
    separation_deg: float,
    distance_m: tuple[float, ...],
    res_deg: float,
    noise_m: float,
    tilt_deg: float,
    height_m: float = 1.5,
    cli: bool = False,
) -> None:
    """Refuse settings :func:`simulate_pair` cannot use, naming the setting.

    Parameters
    ----------
    seed : int
        Must be an integer of 0 or more.
    separation_deg, res_deg, noise_m, tilt_deg, height_m : float
        Must be finite; ``res_deg`` > 0, ``noise_m`` and ``tilt_deg`` >= 0.
    distance_m : tuple of float
        One or two finite distances > 0.
    cli : bool
        Name the settings as ``amrst simulate`` options (``--res-deg``).

    Raises
    ------
    InvalidInput
        The first setting that is wrong, and what it must be.
    """

    def label(name: str) -> str:
        return "--" + name.replace("_", "-") if cli else name

    if (
        isinstance(seed, bool)
        or not isinstance(seed, (int, np.integer))
        or int(seed) < 0
    ):
        raise InvalidInput(
            f"{label('seed')} must be an integer of 0 or more, got {seed!r}."
        )
    numbers = {
        "separation_deg": [separation_deg],
        "distance_m": list(distance_m),
        "res_deg": [res_deg],
        "noise_m": [noise_m],
        "tilt_deg": [tilt_deg],
        "height_m": [height_m],
    }
    for name, values in numbers.items():
        for v in values:
            if not isinstance(v, (int, float, np.number)) or not math.isfinite(v):
                raise InvalidInput(
                    f"{label(name)} must be a finite number, got {v!r}; NaN and "
                    "infinity are not allowed."
                )
    if len(distance_m) not in (1, 2) or min(distance_m) <= 0:
        raise InvalidInput(
            f"{label('distance_m')} must be one positive number or two (target, "
            f"source), got {list(distance_m)}."
        )
    if res_deg <= 0:
        raise InvalidInput(f"{label('res_deg')} must be > 0, got {res_deg}.")
    if noise_m < 0 or tilt_deg < 0:
        raise InvalidInput(
            f"{label('noise_m')} and {label('tilt_deg')} must be >= 0, got "
            f"{noise_m} and {tilt_deg}."
        )
    if tilt_deg > MAX_TILT_DEG:
        raise InvalidInput(
            f"{label('tilt_deg')} must be at most {MAX_TILT_DEG} degrees (a levelled "
            f"tripod tilts under 1), got {tilt_deg:g}."
        )
    if noise_m > MAX_NOISE_M:  # issue 16: 1e6 m wrote a case with no valid point
        raise InvalidInput(
            f"{label('noise_m')} must be at most {MAX_NOISE_M} m (a scanner's range "
            f"noise is millimetres), got {noise_m:g}."
        )


def configure_parser(p: argparse.ArgumentParser) -> None:
    """Add the ``amrst simulate`` arguments to ``p``.

    Parameters
    ----------
    p : argparse.ArgumentParser
    """
    p.add_argument(
        "tree", metavar="TREE", help="complete tree cloud (any readable format)"
    )
    p.add_argument("--out", required=True, metavar="DIR", help="case folder to write")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--separation-deg", type=float, default=90.0)
    p.add_argument(
        "--distance-m",
        type=float,
        nargs="+",
        default=[8.0],
        metavar="D",
        help="trunk-to-scanner distance; give two values for target and source",
    )
    p.add_argument("--res-deg", type=float, default=0.04)
    p.add_argument("--noise-m", type=float, default=0.004)
    p.add_argument("--tilt-deg", type=float, default=0.5)


def run_cli(args: argparse.Namespace) -> int:
    """Simulate a pair from ``args`` (see :func:`configure_parser`) and write the case.

    Parameters
    ----------
    args : argparse.Namespace

    Returns
    -------
    int
        Exit status: 0 on success, 2 when the input cannot be used.
    """
    import sys

    from amrst import io
    from amrst.errors import AmrstError

    distance = (
        args.distance_m[0] if len(args.distance_m) == 1 else tuple(args.distance_m)
    )
    try:
        # Settings and the output folder are checked before the (slow) simulation.
        check_settings(
            seed=args.seed,
            separation_deg=args.separation_deg,
            distance_m=tuple(args.distance_m),
            res_deg=args.res_deg,
            noise_m=args.noise_m,
            tilt_deg=args.tilt_deg,
            cli=True,
        )
        check_case_folder(args.out)
        tree = io.read(args.tree)
        pair = simulate_pair(
            tree,
            seed=args.seed,
            separation_deg=args.separation_deg,
            distance_m=distance,
            res_deg=args.res_deg,
            noise_m=args.noise_m,
            tilt_deg=args.tilt_deg,
        )
        out = write_case(pair, args.out, Path(args.tree).name, args.seed)
    except AmrstError as exc:
        print(f"amrst simulate: {exc}", file=sys.stderr)
        return 2
    print(
        f"{out}: target {len(pair.target)} points, source {len(pair.source)} points, "
        f"shared {pair.shared_fraction:.0%}",
        file=sys.stderr,
    )
    return 0
