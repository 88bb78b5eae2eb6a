"""Read only the points of a vertical cylinder (one tree) from a big plot file.

Private to :mod:`amrst.io` (public as :func:`amrst.io.read_region`). COPC files are
queried spatially, so only the octree nodes touching the cylinder are decompressed.
LAS and LAZ files carry no spatial index: they are streamed in chunks of
``CHUNK_POINTS``, each chunk filtered and dropped, so memory stays bounded by the
chunk and the tree, not the file. Other formats are read whole, then filtered.
"""

from __future__ import annotations

import dataclasses
import logging
from pathlib import Path
from typing import TYPE_CHECKING, Any, NamedTuple

import numpy as np

from amrst.errors import AmrstError, Cancelled, InvalidInput
from amrst.io.common import shorten
from amrst.io.laz import quiet_decoders
from amrst.progress import NULL_REPORTER

if TYPE_CHECKING:
    import os
    from collections.abc import Sequence

    from amrst.io.common import RawCloud
    from amrst.io.las import FixedHeader
    from amrst.progress import Reporter
    from amrst.types import Cloud

logger = logging.getLogger(__name__)

CHUNK_POINTS = 1_000_000


class Cylinder(NamedTuple):
    """A vertical cylinder in world coordinates (m); None: unbounded in z."""

    x: float
    y: float
    radius: float
    zmin: float | None = None
    zmax: float | None = None

    def contains(self, xyz: np.ndarray) -> np.ndarray:
        """Return (N,) bool: which of the world coordinates (N, 3) lie inside."""
        inside = (xyz[:, 0] - self.x) ** 2 + (xyz[:, 1] - self.y) ** 2 <= self.radius**2
        if self.zmin is not None:
            inside &= xyz[:, 2] >= self.zmin
        if self.zmax is not None:
            inside &= xyz[:, 2] <= self.zmax
        return np.asarray(inside)


def read_region(
    path: str | os.PathLike[str],
    stem_xy: Sequence[float],
    radius_m: float,
    *,
    zmin: float | None = None,
    zmax: float | None = None,
    reporter: Reporter = NULL_REPORTER,
) -> Cloud:
    """Read only the points within ``radius_m`` of a stem: one tree of a plot file.

    COPC files are queried through their octree (only the nodes near the stem are
    decompressed); LAS/LAZ files are streamed in chunks with bounded memory;
    other formats are read whole, then cut.

    Parameters
    ----------
    path : str or os.PathLike
        Any readable point-cloud file.
    stem_xy : sequence of 2 floats
        The stem position in the file's world coordinates (m).
    radius_m : float
        Horizontal radius of the cylinder kept (m), > 0.
    zmin, zmax : float, optional
        World height limits of the cylinder (m); default unbounded.
    reporter : Reporter
        Progress and cancellation (streamed files).

    Returns
    -------
    Cloud
        The points inside the cylinder, every attribute kept; ``meta`` adds
        ``clip_method`` and ``clip_points_decoded``.

    Raises
    ------
    InvalidInput
        What :func:`read` refuses, a non-positive radius, zmin above zmax, or no
        point inside the cylinder (the message gives the file's extent).
    """
    from amrst import io

    path = Path(path)
    cylinder = Cylinder(*check_cylinder(stem_xy, radius_m, zmin, zmax))
    try:
        fmt = io.check_readable(path)
    except PermissionError as exc:
        raise io._permission_denied(path) from exc
    if fmt.label not in ("las", "laz"):
        cloud = io.read(path)
        inside = cylinder.contains(cloud.xyz + cloud.offset)
        extent = _extent_text(
            cloud.xyz.min(axis=0) + cloud.offset, cloud.xyz.max(axis=0) + cloud.offset
        )
        if not inside.any():
            raise _nothing_inside(path, cylinder, extent)
        return _with_meta(
            cloud.select(inside),
            clip_method="whole file",
            clip_points_decoded=len(cloud),
        )
    try:
        raw, how = read_las_region(path, cylinder, reporter)
    except (AmrstError, Cancelled):
        raise
    except PermissionError as exc:
        raise io._permission_denied(path) from exc
    except Exception as exc:
        raise InvalidInput(
            f"Could not read {path}: {shorten(str(exc), 200)} "
            f"({type(exc).__name__}). The file looks corrupt or truncated; "
            "export it again."
        ) from exc
    if raw is None:
        raise _nothing_inside(path, cylinder, str(how["clip_file_bounds"]))
    cloud = io._finish(raw, path, fmt.label)
    return _with_meta(
        cloud,
        clip_method=how["clip_method"],
        clip_points_decoded=how["clip_points_decoded"],
    )


def _with_meta(cloud: Cloud, **meta: object) -> Cloud:
    return dataclasses.replace(cloud, meta={**cloud.meta, **meta})


def check_cylinder(
    stem_xy: Sequence[float], radius_m: float, zmin: float | None, zmax: float | None
) -> tuple[float, float, float, float | None, float | None]:
    """Return the clip's stem, radius and heights as numbers, or refuse them."""
    from amrst.types import MAX_COORD_M

    def within(v: float) -> bool:
        return bool(abs(v) <= MAX_COORD_M)  # False for NaN

    if len(stem_xy) != 2 or not all(within(v) for v in stem_xy):
        raise InvalidInput(
            f"The stem position must be two numbers X Y within {MAX_COORD_M:g} m "
            f"(got {', '.join(f'{v:.6g}' for v in stem_xy)})."
        )
    if not (radius_m > 0 and within(radius_m)):
        raise InvalidInput(
            f"The clip radius must be a positive number of metres (got "
            f"{radius_m:.6g}); a tree needs about 2-10 m."
        )
    if not all(within(v) for v in (zmin, zmax) if v is not None):
        raise InvalidInput(
            f"zmin and zmax must be heights within {MAX_COORD_M:g} m (got "
            f"{zmin if zmin is None else f'{zmin:.6g}'}, "
            f"{zmax if zmax is None else f'{zmax:.6g}'})."
        )
    if zmin is not None and zmax is not None and zmin >= zmax:
        raise InvalidInput(
            f"zmin ({zmin} m) must be below zmax ({zmax} m); swap them or drop one."
        )
    return float(stem_xy[0]), float(stem_xy[1]), float(radius_m), zmin, zmax


def _extent_text(lo: np.ndarray, hi: np.ndarray) -> str:
    return f"x {lo[0]:.2f}..{hi[0]:.2f}, y {lo[1]:.2f}..{hi[1]:.2f}"


def _nothing_inside(path: Path, cylinder: Cylinder, extent: str) -> InvalidInput:
    x, y, r = cylinder.x, cylinder.y, cylinder.radius
    return InvalidInput(
        f"{path}: no point lies within {r:g} m of the stem ({x:g}, {y:g}) in the "
        f"height range given. The file spans {extent}: give the stem in the "
        "file's own coordinates, or a larger radius."
    )


def read_las_region(
    path: Path, cylinder: Cylinder, reporter: Reporter
) -> tuple[RawCloud | None, dict[str, Any]]:
    """Return the cylinder's points of a LAS/LAZ/COPC file (None: none), and how."""
    from amrst.io.las import check_header, las_to_raw

    fixed = check_header(path)
    copc = _copc_query(path, cylinder)
    # A COPC index lists points in every region of the file (its root node holds a
    # sample of them all); one that lists none where the header says points lie is
    # corrupt: the file is then read as any LAZ, which finds the points or the fault.
    if copc is not None and (copc[2] or not _meets(fixed, cylinder)):
        las, n_decoded, _ = copc
        how = {"clip_method": "copc spatial query", "clip_points_decoded": n_decoded}
    else:
        las, n_decoded = _stream(path, fixed, cylinder, reporter)
        how = {"clip_method": "streamed chunks", "clip_points_decoded": n_decoded}
    how["clip_file_bounds"] = (
        f"x {fixed.mins[0]:.2f}..{fixed.maxs[0]:.2f}, "
        f"y {fixed.mins[1]:.2f}..{fixed.maxs[1]:.2f}"
    )
    if len(las) == 0:
        return None, how
    return las_to_raw(las, fixed, path), how


def _meets(fixed: FixedHeader, cylinder: Cylinder) -> bool:
    """Tell whether the cylinder's box meets the file's bounds (its header's)."""
    r = cylinder.radius
    return bool(
        cylinder.x + r >= fixed.mins[0]
        and cylinder.x - r <= fixed.maxs[0]
        and cylinder.y + r >= fixed.mins[1]
        and cylinder.y - r <= fixed.maxs[1]
        and (cylinder.zmin is None or cylinder.zmin <= fixed.maxs[2])
        and (cylinder.zmax is None or cylinder.zmax >= fixed.mins[2])
    )


def _copc_query(path: Path, cylinder: Cylinder) -> tuple[Any, int, int] | None:
    """Query a COPC file's octree for the cylinder's box (None: not COPC).

    Returns the points in the cylinder, how many were decoded in its box, and how
    many the index lists in the nodes that meet the box.
    """
    import laspy
    from laspy.copc import load_octree_for_query

    with open(path, "rb") as f:
        head = f.read(375 + 54)
    if len(head) < 429 or head[377:381] != b"copc":  # COPC info: the first VLR
        return None
    lo_z = -np.inf if cylinder.zmin is None else cylinder.zmin
    hi_z = np.inf if cylinder.zmax is None else cylinder.zmax
    r = cylinder.radius
    with quiet_decoders(), laspy.CopcReader.open(str(path)) as reader:
        header = reader.header
        bounds = laspy.Bounds(
            mins=np.array([cylinder.x - r, cylinder.y - r, max(lo_z, header.mins[2])]),
            maxs=np.array([cylinder.x + r, cylinder.y + r, min(hi_z, header.maxs[2])]),
        )
        nodes = load_octree_for_query(
            reader.source,
            reader.copc_info,
            reader.root_page,
            query_bounds=bounds.ensure_3d(header.mins, header.maxs),
        )
        listed = sum(max(0, node.point_count) for node in nodes)
        points = reader.query(bounds)
        n_decoded = len(points)
        keep = cylinder.contains(np.column_stack([points.x, points.y, points.z]))
        record = laspy.ScaleAwarePointRecord(
            points.array[keep], header.point_format, header.scales, header.offsets
        )
        return laspy.LasData(header=header, points=record), n_decoded, listed


def _stream(
    path: Path, fixed: FixedHeader, cylinder: Cylinder, reporter: Reporter
) -> tuple[Any, int]:
    """Stream the file in chunks, keeping the cylinder's points only."""
    import laspy

    from amrst.io.las import open_points

    kept: list[np.ndarray] = []
    n_read = 0
    with open_points(path, fixed) as reader:
        header = reader.header
        total = max(int(header.point_count), 1)
        scales = np.asarray(header.scales, np.float64)
        offsets = np.asarray(header.offsets, np.float64)
        chunks = reader.chunk_iterator(CHUNK_POINTS)
        while True:
            reporter.check_cancelled()
            with quiet_decoders():
                chunk = next(chunks, None)
            if chunk is None or len(chunk) == 0:
                break
            arr = chunk.array
            world = np.column_stack(
                [arr[c] * s + o for c, s, o in zip("XYZ", scales, offsets, strict=True)]
            )
            kept.append(arr[cylinder.contains(world)])
            n_read += len(arr)
            reporter.progress(min(n_read / total, 1.0), f"clip: {n_read:,} points read")
        record = laspy.ScaleAwarePointRecord(
            np.concatenate(kept) if kept else np.zeros(0, header.point_format.dtype()),
            header.point_format,
            header.scales,
            header.offsets,
        )
    return laspy.LasData(header=header, points=record), n_read


def read_overview(
    path: str | os.PathLike[str],
    max_points: int = 200_000,
    reporter: Reporter = NULL_REPORTER,
) -> Cloud:
    """Read an evenly thinned sample of a plot file, for a top view to click in.

    LAS/LAZ/COPC are streamed in chunks keeping every k-th point (bounded
    memory); other formats are read whole, then thinned. Attributes are dropped.

    Parameters
    ----------
    path : str or os.PathLike
    max_points : int
        At most about this many points are kept.
    reporter : Reporter

    Returns
    -------
    Cloud
        The sample (``meta["overview_of"]``: the file's point count).
    """
    from amrst import io
    from amrst.io.las import check_header, open_points
    from amrst.types import Cloud

    path = Path(path)
    fmt = io.check_readable(path)
    if fmt.label not in ("las", "laz"):
        cloud = io.read(path)
        step = max(1, -(-len(cloud) // max_points))
        return Cloud(
            cloud.xyz[::step], cloud.offset, {}, cloud.name, {"overview_of": len(cloud)}
        )
    fixed = check_header(path)
    parts: list[np.ndarray] = []
    try:
        with open_points(path, fixed) as reader:
            total = int(reader.header.point_count)
            step = max(1, -(-total // max_points))
            scales = np.asarray(reader.header.scales, np.float64)
            chunks = reader.chunk_iterator(CHUNK_POINTS)
            n_read = 0
            while True:
                reporter.check_cancelled()
                with quiet_decoders():
                    chunk = next(chunks, None)
                if chunk is None or len(chunk) == 0:
                    break
                arr = chunk.array[(n_read + np.arange(len(chunk))) % step == 0]
                parts.append(
                    np.column_stack(
                        [arr[c] * s for c, s in zip("XYZ", scales, strict=True)]
                    )
                )
                n_read += len(chunk)
                reporter.progress(min(n_read / max(total, 1), 1.0), "overview")
            offset = np.asarray(reader.header.offsets, np.float64)
    except (AmrstError, Cancelled):
        raise
    except Exception as exc:
        raise InvalidInput(
            f"Could not read {path}: {shorten(str(exc), 200)} "
            f"({type(exc).__name__}). The file looks corrupt or truncated; "
            "export it again."
        ) from exc
    xyz = np.vstack(parts) if parts else np.zeros((0, 3))
    return Cloud(xyz, offset, {}, path.name, {"overview_of": n_read})
