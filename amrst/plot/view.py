"""What a plot's results keep for the app to draw (``view.npz``).

Each tree's stem slices and a sample of its points (its side view), the top view and
each scan's offset; where the scanners stood is plot.json's (:func:`scanner_position`).

A run writes it beside plot.json and trees.csv (``plot.export.write_plot``), so a
plot's results open in the app without running it again, whether the app or
``amrst plot`` wrote them. Positions are in the reference scan's local frame: the
files' coordinates less the reference's offset (``offsets[reference]``).
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np

from amrst.errors import InvalidInput
from amrst.plot.diameter import BREAST_HEIGHT_M, SLICE_HALF_M

if TYPE_CHECKING:
    from collections.abc import Callable, Mapping, Sequence
    from pathlib import Path

    from amrst.plot.inventory import Inventory
    from amrst.types import Cloud

VIEW_NPZ = "view.npz"
#: The layout of view.npz; a file of another is refused (run the plot again).
VIEW_FORMAT = 1
#: The slices shown per tree: their middles above the local ground (breast height
#: the DBH's, the others to see the stem below and above it), as thick as the DBH's.
SLICE_HEIGHTS_M = (0.6, BREAST_HEIGHT_M, 2.0, 3.0)
#: The slices follow the stem line: through the DBH centre, leaning as the stem map
#: measured, towards the DBH centre from the foot; at most ``MAX_LEAN_PER_M``.
MAX_LEAN_PER_M = 0.2
#: Points kept around the stem in the slice (m beyond its radius).
SLICE_MARGIN_M = 0.3
#: Cell of the top view (m), and the most cells it has across.
TOP_CELL_M = 0.25
TOP_MAX_CELLS = 2000
#: Vegetation in the top view: points this high above the ground.
TOP_MIN_HEIGHT_M = 0.5
#: A tree's side view: at most this many of its points, evenly strided.
PROFILE_POINTS = 4000


@dataclass(frozen=True, slots=True)
class TreeSlice:
    """The points around one stem at one height and the scan each came from."""

    xy: np.ndarray  # (N, 2) reference local frame
    scan: np.ndarray  # (N,) 0-based scan index
    height_m: float = BREAST_HEIGHT_M  # above the local ground
    centre: np.ndarray | None = None  # (2,) the stem line there; None: the DBH's


@dataclass(frozen=True, slots=True)
class TopView:
    """Vegetation density seen from above: ``image[row, col]``, row 0 at ``y0``."""

    image: np.ndarray  # (H, W) uint8
    x0: float
    y0: float
    cell_m: float


@dataclass(frozen=True, slots=True)
class TreeProfile:
    """Some of one tree's points (its side view) and the scan each came from."""

    xyz: np.ndarray  # (N, 3) reference local frame
    scan: np.ndarray  # (N,) 0-based scan index


@dataclass(frozen=True, slots=True)
class PlotView:
    """The drawing of a plot: scans' offsets, trees' centres, slices and side views.

    ``trees`` follows trees.csv's order (tree ids); ``slices[k]`` holds one slice per
    ``SLICE_HEIGHTS_M`` for tree k.
    """

    offsets: np.ndarray  # (S, 3) each scan's offset (its files' coordinates - local)
    trees: tuple[str, ...]
    dbh_xy: np.ndarray  # (T, 2) breast-height centre of each tree
    slices: tuple[tuple[TreeSlice, ...], ...]
    profiles: tuple[TreeProfile, ...]
    top: TopView | None


def plot_view(clouds: Sequence[Cloud], inventory: Inventory) -> PlotView:
    """Return the drawing of a registered, inventoried plot of ``clouds``."""
    return PlotView(
        offsets=np.array([c.offset for c in clouds], float).reshape(-1, 3),
        trees=tuple(t.tree_id for t in inventory.trees),
        dbh_xy=np.array([t.stem.dbh_xy for t in inventory.trees], float).reshape(-1, 2),
        slices=tree_slices(inventory),
        profiles=tree_profiles(inventory),
        top=top_view(inventory),
    )


def tree_slices(inventory: Inventory) -> tuple[tuple[TreeSlice, ...], ...]:
    """Return, per tree, the merged plot's points around its stem at each height.

    Slices at ``SLICE_HEIGHTS_M`` (± ``SLICE_HALF_M`` above the local ground) follow
    the stem line (``MAX_LEAN_PER_M``).
    """
    from scipy.spatial import cKDTree

    sm = inventory.stem_map
    if not inventory.trees:
        return ()
    xy_tree = cKDTree(sm.xyz[:, :2])
    offset = MAX_LEAN_PER_M * max(abs(z - BREAST_HEIGHT_M) for z in SLICE_HEIGHTS_M)
    out = []
    for tree in inventory.trees:
        stem = tree.stem
        dbh_xy = np.asarray(stem.dbh_xy, float)
        towards = dbh_xy - np.asarray(stem.base[:2], float)
        norm = float(np.hypot(*towards))
        per_m = min(np.tan(np.radians(np.nan_to_num(stem.lean_deg))), MAX_LEAN_PER_M)
        lean = towards / norm * per_m if norm > 1e-3 else np.zeros(2)
        radius = (stem.dbh_m / 2 if np.isfinite(stem.dbh_m) else 0.2) + SLICE_MARGIN_M
        near = np.sort(np.asarray(xy_tree.query_ball_point(dbh_xy, radius + offset)))
        near = near.astype(np.int64)
        h = sm.ground.height(sm.xyz[near]) if len(near) else np.zeros(0)
        slices = []
        for z in SLICE_HEIGHTS_M:
            centre = dbh_xy + lean * (z - BREAST_HEIGHT_M)
            keep = near[
                (np.abs(h - z) <= SLICE_HALF_M)
                & (np.hypot(*(sm.xyz[near, :2] - centre).T) <= radius)
            ]
            slices.append(
                TreeSlice(
                    np.asarray(sm.xyz[keep, :2], float),
                    np.asarray(inventory.scan_of_point[keep], np.int64),
                    z,
                    centre,
                )
            )
        out.append(tuple(slices))
    return tuple(out)


def tree_profiles(inventory: Inventory) -> tuple[TreeProfile, ...]:
    """Return, per tree, at most ``PROFILE_POINTS`` of its points, evenly strided."""
    sm = inventory.stem_map
    order = np.argsort(sm.owner, kind="stable")
    ends = np.searchsorted(sm.owner[order], np.arange(len(inventory.trees) + 1))
    out = []
    for k in range(len(inventory.trees)):
        rows = order[ends[k] : ends[k + 1]]
        rows = rows[:: max(1, -(-len(rows) // PROFILE_POINTS))]  # stride rounded up
        out.append(
            TreeProfile(
                np.asarray(sm.xyz[rows], float),
                np.asarray(inventory.scan_of_point[rows], np.int64),
            )
        )
    return tuple(out)


def top_view(inventory: Inventory) -> TopView | None:
    """Return the plot's vegetation seen from above (log density); None: no ground."""
    sm = inventory.stem_map
    if not sm.ground.found or not len(sm.xyz):
        return None
    pts = sm.xyz[sm.ground.height(sm.xyz) >= TOP_MIN_HEIGHT_M]
    if not len(pts):
        return None
    # Cells grow where the plot is wider than TOP_MAX_CELLS across (a scan in
    # millimetres, a stray point far out): the image stays a drawing's size.
    span = float(np.ptp(pts[:, :2], axis=0).max())
    cell = max(TOP_CELL_M, span / (TOP_MAX_CELLS - 1))
    lo = np.floor(pts[:, :2].min(axis=0) / cell) * cell
    cells = np.minimum(
        np.floor((pts[:, :2] - lo) / cell).astype(np.int64), TOP_MAX_CELLS - 1
    )
    shape = cells.max(axis=0) + 1
    counts = np.zeros((shape[1], shape[0]), np.float64)
    np.add.at(counts, (cells[:, 1], cells[:, 0]), 1.0)
    scaled = np.log1p(counts) / max(float(np.log1p(counts.max())), 1e-9)
    image = np.round(255 * scaled).astype(np.uint8)
    return TopView(image, float(lo[0]), float(lo[1]), cell)


def view_writer(view: PlotView) -> Callable[[Path], object]:
    """Return the writer of ``view`` as view.npz.

    Compressed; slices as float32, which keeps millimetres within a few kilometres of
    the reference.
    """
    sizes = np.array([[len(s.xy) for s in tree] for tree in view.slices], np.int64)
    centres = np.array(
        [
            [np.full(2, np.nan) if s.centre is None else s.centre for s in tree]
            for tree in view.slices
        ],
        float,
    )
    flat = [s for tree in view.slices for s in tree]
    arrays: dict[str, np.ndarray] = {
        "format": np.array(VIEW_FORMAT),
        "offsets": view.offsets,
        "trees": np.array(view.trees, dtype=str),
        "dbh_xy": view.dbh_xy,
        "slice_heights_m": np.array(SLICE_HEIGHTS_M, float),
        "slice_sizes": sizes.reshape(len(view.trees), len(SLICE_HEIGHTS_M)),
        "slice_centres": centres.reshape(len(view.trees), len(SLICE_HEIGHTS_M), 2),
        "slice_xy": np.concatenate([s.xy for s in flat] or [np.zeros((0, 2))]).astype(
            np.float32
        ),
        "slice_scan": np.concatenate(
            [s.scan for s in flat] or [np.zeros(0, np.int64)]
        ).astype(np.uint16),
    }
    arrays |= {
        "profile_sizes": np.array([len(t.xyz) for t in view.profiles], np.int64),
        "profile_xyz": np.concatenate(
            [t.xyz for t in view.profiles] or [np.zeros((0, 3))]
        ).astype(np.float32),
        "profile_scan": np.concatenate(
            [t.scan for t in view.profiles] or [np.zeros(0, np.int64)]
        ).astype(np.uint16),
    }
    if view.top is not None:
        arrays["top_image"] = view.top.image
        arrays["top_origin"] = np.array([view.top.x0, view.top.y0, view.top.cell_m])

    def write(path: Path) -> None:
        with path.open("wb") as fh:
            np.savez_compressed(fh, **arrays)  # type: ignore[arg-type]

    return write


def read_view(path: Path) -> PlotView:
    """Read view.npz.

    Raises
    ------
    InvalidInput
        Missing, unreadable, or of another layout (run the plot again).
    """
    import zipfile

    if os.path.lexists(path) and not path.is_file():  # a FIFO would block open()
        raise InvalidInput(
            f"{path} is not a file (a folder, a named pipe...): run the plot again."
        )
    try:
        with path.open("rb") as fh, np.load(fh, allow_pickle=False) as f:
            data = {k: f[k] for k in f.files}
        if int(data["format"]) != VIEW_FORMAT:
            raise ValueError(f"layout {int(data['format'])}, not {VIEW_FORMAT}")
        return _view(data)
    except FileNotFoundError as exc:
        raise InvalidInput(
            f"{path.parent} has no {path.name} (an older run): run the plot again."
        ) from exc
    except (
        OSError,
        EOFError,  # an empty file
        ValueError,
        KeyError,
        IndexError,
        TypeError,
        zipfile.BadZipFile,
    ) as exc:
        raise InvalidInput(
            f"{path} cannot be read ({exc}): run the plot again."
        ) from exc


def _view(data: dict[str, np.ndarray]) -> PlotView:
    heights = tuple(float(z) for z in data["slice_heights_m"])
    sizes = data["slice_sizes"].reshape(-1, len(heights))
    trees = tuple(str(t) for t in data["trees"])
    if len(sizes) != len(trees) or int(sizes.sum()) != len(data["slice_xy"]):
        raise ValueError("slices do not match the trees")
    ends = np.cumsum(sizes.ravel())
    xy = np.split(np.asarray(data["slice_xy"], float), ends[:-1])
    scan = np.split(np.asarray(data["slice_scan"], np.int64), ends[:-1])
    centres = data["slice_centres"].reshape(len(trees), len(heights), 2)
    slices = tuple(
        tuple(
            TreeSlice(
                xy[k * len(heights) + j],
                scan[k * len(heights) + j],
                z,
                None if np.isnan(centres[k, j]).any() else centres[k, j],
            )
            for j, z in enumerate(heights)
        )
        for k in range(len(trees))
    )
    sizes = np.asarray(data["profile_sizes"], np.int64)
    if (
        len(sizes) != len(trees)
        or (sizes < 0).any()
        or int(sizes.sum()) != len(data["profile_xyz"])
    ):
        raise ValueError("side views do not match the trees")
    stops = np.cumsum(sizes, dtype=np.int64)
    starts = stops - sizes
    pxyz = np.asarray(data["profile_xyz"], float).reshape(-1, 3)
    pscan = np.asarray(data["profile_scan"], np.int64)
    profiles = tuple(
        TreeProfile(pxyz[a:b], pscan[a:b]) for a, b in zip(starts, stops, strict=True)
    )
    top = None
    if "top_image" in data:
        x0, y0, cell = (float(v) for v in data["top_origin"])
        top = TopView(np.asarray(data["top_image"], np.uint8), x0, y0, cell)
    return PlotView(
        offsets=np.asarray(data["offsets"], float).reshape(-1, 3),
        trees=trees,
        dbh_xy=np.asarray(data["dbh_xy"], float).reshape(len(trees), 2),
        slices=slices,
        profiles=profiles,
        top=top,
    )


def scanner_position(scan: Mapping[str, Any]) -> np.ndarray | None:
    """(3,) where a plot.json scan's scanner stood, the reference's file coordinates.

    A plot.json written before ``scanner_xyz`` existed gives the scan's file origin,
    unless that lies in georeferenced coordinates (not known then).
    """
    from amrst.io.common import LARGE_COORD_M

    if "scanner_xyz" in scan:
        at = scan["scanner_xyz"]
        return None if at is None else np.asarray(at, dtype=float)
    T = scan.get("T_reference_scan")
    if T is None:
        return None
    origin = np.asarray(T, dtype=float).reshape(4, 4)[:3, 3]
    return None if np.abs(origin).max() > LARGE_COORD_M else origin
