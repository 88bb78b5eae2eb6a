"""Read and write point clouds: LAS/LAZ, PLY, PCD and delimited text.

Every format is registered once in ``_FORMATS`` (napari's reader convention:
:func:`get_reader` returns a callable or None). Readers keep every attribute and
georeferenced precision: large coordinates are split into a float64 ``offset`` plus
small float64 local values. Writes are atomic (a temp file in the same folder, then
``os.replace``). Every failure is an :class:`~amrst.errors.InvalidInput` or
:class:`~amrst.errors.AmrstError` whose message says what is wrong and what to do.
"""

from __future__ import annotations

import errno
import functools
import logging
import os
import stat
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from amrst.errors import AmrstError, InvalidInput
from amrst.files.atomic import write_atomic
from amrst.files.safefile import refuse_undecodable
from amrst.io.common import RawCloud, rebase, shorten
from amrst.io.describe import describe, format_description
from amrst.io.e57 import read_e57
from amrst.io.las import read_las
from amrst.io.las_write import PointLabels, write_las, write_las_parts
from amrst.io.pcd import read_pcd, write_pcd
from amrst.io.ply import read_ply, write_ply
from amrst.io.ptx import read_ptx
from amrst.io.region import read_overview, read_region
from amrst.io.text import read_text, write_text
from amrst.progress import NULL_REPORTER, Reporter
from amrst.types import MAX_COORD_M, Cloud, Transform

logger = logging.getLogger(__name__)

PathLike = str | os.PathLike[str]
Reader = Callable[..., Cloud]


@dataclass(frozen=True)
class _Format:
    label: str
    read: Callable[..., RawCloud]
    write: Callable[..., None] | None
    text: bool = False
    chunked: bool = False  # reads in steps, with a reporter (progress, Cancel)


_TEXT_CSV = functools.partial(write_text, sep=",")
_FORMATS: dict[str, _Format] = {
    ".las": _Format("las", read_las, write_las, chunked=True),
    ".laz": _Format(
        "laz", read_las, functools.partial(write_las, compress=True), chunked=True
    ),
    ".ply": _Format("ply", read_ply, write_ply),
    ".pcd": _Format("pcd", read_pcd, write_pcd),
    ".xyz": _Format("text", read_text, write_text, text=True),
    ".txt": _Format("text", read_text, write_text, text=True),
    ".asc": _Format("text", read_text, None, text=True),
    ".csv": _Format("text", read_text, _TEXT_CSV, text=True),
    ".pts": _Format("text", read_text, None, text=True),
    ".e57": _Format("e57", read_e57, None),  # several scans: see amrst.io.scans
    ".ptx": _Format("ptx", read_ptx, None),  # several scans: see amrst.io.scans
}
# The atomic writer looks writers up here, so tests can make one fail midway.
_WRITERS = {ext: fmt.write for ext, fmt in _FORMATS.items() if fmt.write is not None}


def supported_extensions() -> tuple[str, ...]:
    """File extensions :func:`read` understands (lower case, with the dot).

    Returns
    -------
    tuple of str
        E.g. ``(".las", ".laz", ".ply", ...)``.
    """
    return tuple(_FORMATS)


def writable_extensions() -> tuple[str, ...]:
    """File extensions :func:`write` can produce (lower case, with the dot)."""
    return tuple(_WRITERS)


def get_reader(path: PathLike) -> Reader | None:
    """Return the reader for ``path``, or None when its extension is not supported.

    Parameters
    ----------
    path : str or os.PathLike
        A point-cloud file name; only its extension is looked at.

    Returns
    -------
    callable or None
        ``reader(path) -> Cloud`` (this module's :func:`read`), or None.
    """
    return read if Path(path).suffix.lower() in _FORMATS else None


def check_readable(path: Path) -> _Format:
    """Check what ``path`` is before opening it: never block on a FIFO or a device.

    Only looks at the path and its ``stat`` (so it may run on a GUI thread): a
    missing or empty file, a folder, a pipe or device, an extension no reader takes.
    A file name that is not UTF-8 is refused too: the results, reports and tables
    that name the scan could not write it.

    Raises
    ------
    InvalidInput
        Any of those, in one line that says what to give instead.
    """
    refuse_undecodable(path, " (the file or its folder)")
    try:
        info = path.stat()
    except FileNotFoundError:
        if path.is_symlink():
            raise InvalidInput(
                f"{path} is a broken link: it points to {os.readlink(path)}, which "
                "does not exist. Fix the link or give the real file."
            ) from None
        head, sep, tail = str(path).rpartition("#")
        if sep and Path(head).is_file():
            raise InvalidInput(
                f"{path}: '#{tail}' picks one scan of a multi-scan file for amrst "
                f"register, plot and info (numbered from 0); amrst info {head} lists "
                "the scans it holds."
            ) from None
        raise InvalidInput(
            f"File not found: {path}. Check the path and the file name."
        ) from None
    except OSError as exc:
        if exc.errno == errno.ELOOP:
            raise InvalidInput(
                f"{path} is a symbolic link loop (the links point at each other). "
                "Fix the links or give the real file."
            ) from exc
        if isinstance(exc, PermissionError):
            raise
        raise InvalidInput(
            f"Cannot read {path}: {exc.strerror or exc}. Check the path."
        ) from exc
    if stat.S_ISDIR(info.st_mode):
        raise InvalidInput(
            f"{path} is a folder, not a point-cloud file. Choose a file ending in "
            f"{', '.join(_FORMATS)}."
        )
    if not stat.S_ISREG(info.st_mode):
        kind = (
            "a named pipe (FIFO)" if stat.S_ISFIFO(info.st_mode)
            else "a character device" if stat.S_ISCHR(info.st_mode)
            else "a block device" if stat.S_ISBLK(info.st_mode)
            else "a socket" if stat.S_ISSOCK(info.st_mode)
            else "not a regular file"
        )  # fmt: skip
        raise InvalidInput(
            f"{path} is {kind}, not a point-cloud file. Save the cloud to a "
            "regular file first and give that file."
        )
    fmt = _FORMATS.get(path.suffix.lower())
    if fmt is None:
        raise InvalidInput(
            f"Cannot read {path.name}: unsupported extension '{path.suffix}'. "
            f"Supported: {', '.join(_FORMATS)}. Convert the file (e.g. with "
            "CloudCompare) to one of these."
        )
    if info.st_size == 0:
        raise InvalidInput(
            f"{path} is empty (0 bytes). The export or copy probably failed; "
            "export it again."
        )
    return fmt


def read(
    path: PathLike,
    *,
    columns: Sequence[str] | None = None,
    reporter: Reporter = NULL_REPORTER,
) -> Cloud:
    """Read a point cloud, keeping every attribute and georeferenced precision.

    Parameters
    ----------
    path : str or os.PathLike
        A ``.las .laz .ply .pcd .xyz .txt .asc .csv .pts`` file.
    columns : sequence of str, optional
        Text files only: names of the columns in order, e.g.
        ``["x", "y", "z", "intensity", "red", "green", "blue"]``; must include
        x, y and z. Default: the header's names, else x, y, z, intensity, col4...
    reporter : Reporter
        Progress and Cancel while LAS/LAZ points are decoded.

    Returns
    -------
    Cloud
        ``xyz`` (N, 3) float64 local coordinates, ``offset`` (3,) float64,
        ``attributes`` per point, ``meta`` with ``format``, ``path`` and format
        details. Points with NaN/inf coordinates or coordinates beyond 1e9 m are
        dropped (logged as a warning; the count is kept in
        ``meta["n_dropped_invalid"]``): a Cloud cannot hold them.

    Raises
    ------
    InvalidInput
        Missing, unreadable (permissions) or empty file, a folder, unsupported
        extension, corrupt or truncated file, a non-numeric text line, or no
        valid point.
    Cancelled
        ``reporter`` asked to stop (LAS/LAZ: checked between chunks of points).
    """
    path = Path(path)
    try:
        fmt = check_readable(path)
    except PermissionError as exc:  # a folder on the way cannot be searched
        raise _permission_denied(path) from exc
    if columns is not None and not fmt.text:
        logger.warning(
            "columns= applies to text files only; ignored for %s.", path.name
        )
    try:
        if fmt.text:
            raw = fmt.read(path, columns)
        else:
            raw = fmt.read(path, reporter) if fmt.chunked else fmt.read(path)
        reporter.check_cancelled()
    except AmrstError:
        raise
    except PermissionError as exc:
        raise _permission_denied(path) from exc
    except MemoryError as exc:
        raise InvalidInput(
            f"{path} is too large to load into memory. Cut the tree out first "
            "(amrst clip) or thin the cloud."
        ) from exc
    except Exception as exc:  # any library error becomes a message the user can act on
        raise InvalidInput(
            f"Could not read {path}: {shorten(str(exc), 200)} "
            f"({type(exc).__name__}). The file looks corrupt or truncated, or is "
            f"not really a {fmt.label} file; export it again."
        ) from exc
    return _finish(raw, path, fmt.label)


def _permission_denied(path: Path) -> InvalidInput:
    return InvalidInput(
        f"Cannot read {path}: permission denied: fix the file's permissions or "
        "copy it somewhere readable."
    )


def _finish(raw: RawCloud, path: Path, label: str, source: str | None = None) -> Cloud:
    """Drop invalid rows, choose the offset and build the Cloud.

    Invalid rows have a NaN, inf or absurd (beyond ``MAX_COORD_M``) world
    coordinate. ``source`` names what was read in messages (one scan of a
    multi-scan file); the file by default.
    """
    source = source or str(path)
    valid = _valid_rows(raw.xyz, raw.offset)
    n_valid = int(valid.sum())
    if len(valid) == 0:
        raise InvalidInput(
            f"{source} contains no points. Check that the export finished and "
            "wrote the points."
        )
    if n_valid == 0:
        text = any(f.text for f in _FORMATS.values() if f.label == label)
        columns = (
            ", the units or the column order (columns=)" if text else " or the units"
        )
        raise InvalidInput(
            f"{source} contains no valid points ({len(valid)} rows, none with finite "
            f"x, y, z within 1e9 m). Check the export{columns}."
        )
    n_dropped = len(valid) - n_valid
    with np.errstate(over="ignore", invalid="ignore"):
        n_far = int(np.isfinite(raw.xyz + raw.offset).all(axis=1).sum()) - n_valid
    if n_far > n_valid:  # most of the scan, not a few stray rows: the units
        raise InvalidInput(
            f"{source}: {n_far:,} of its {len(valid):,} points lie beyond 1e9 m. "
            "Check the units (metres) and the offset of the export."
        )
    xyz, attributes = raw.xyz, raw.attributes
    if n_dropped:
        logger.warning(
            "%s: dropped %d of %d points with NaN/inf coordinates or coordinates "
            "beyond 1e9 m.",
            path.name,
            n_dropped,
            len(valid),
        )
        xyz = xyz[valid]
        attributes = {k: v[valid] for k, v in attributes.items()}
    local, offset = rebase(xyz, raw.offset + 0.0)  # + 0.0 turns -0.0 into 0.0
    span = [float(local[:, d].max() - local[:, d].min()) for d in range(3)]
    if max(span) > MAX_COORD_M:  # no local frame holds it: the rows are not a scan
        d = int(np.argmax(span))
        raise InvalidInput(
            f"{source}: its points span {span[d]:.3g} m along {'xyz'[d]}: no scan is "
            "that large. Check the export (units, columns), or drop the stray rows."
        )
    meta = {"format": label, "path": str(path), "n_dropped_invalid": n_dropped}
    return Cloud(local, offset, attributes, path.name, {**meta, **raw.meta})


def _valid_rows(xyz: np.ndarray, offset: np.ndarray) -> np.ndarray:
    """(N,) bool: rows whose world x, y, z are finite and within ``MAX_COORD_M``."""
    with np.errstate(over="ignore", invalid="ignore"):
        world = np.asarray(xyz, dtype=np.float64) + np.asarray(offset, np.float64)
        return np.asarray((np.abs(world) <= MAX_COORD_M).all(axis=1))  # NaN: False


def write(path: PathLike, cloud: Cloud, *, binary: bool = True) -> None:
    """Write a cloud atomically, keeping attributes and world-coordinate precision.

    Parameters
    ----------
    path : str or os.PathLike
        Destination ending in ``.las .laz .ply .pcd .xyz .txt .csv``. An existing
        file is replaced only once the new one is completely written.
    cloud : Cloud
        The cloud; world coordinates ``xyz + offset`` are written.
    binary : bool
        PLY and PCD: binary (default) or ASCII. Ignored by other formats.

    Raises
    ------
    InvalidInput
        Unsupported extension, missing folder, or the path is a folder.
    AmrstError
        The file could not be written (permissions, full disk, ...).
    """
    path = Path(path)
    writer = _WRITERS.get(path.suffix.lower())
    if writer is None:
        raise InvalidInput(
            f"Cannot write {path.name}: unsupported extension '{path.suffix}'. "
            f"Choose one of {', '.join(_WRITERS)}."
        )
    if not path.parent.is_dir():
        raise InvalidInput(
            f"Cannot write {path}: the folder {path.parent} does not exist. "
            "Create it or choose another folder."
        )
    if path.is_dir():
        raise InvalidInput(f"Cannot write {path}: it is a folder. Choose a file name.")
    write_atomic(path, lambda tmp: writer(tmp, cloud, binary=binary))


def write_merged(
    path: PathLike,
    parts: Sequence[Cloud],
    moves: Sequence[Transform],
    offset: np.ndarray,
    ids: Sequence[int],
    *,
    load: Callable[[int], Cloud] | None = None,
    labels: PointLabels | None = None,
) -> None:
    """Write clouds moved into one frame as one LAS or LAZ file, atomically.

    ``moves[k]`` takes ``parts[k]``'s local coordinates into the frame whose origin is
    ``offset`` (world coordinates); part k's points get ``scan_id`` ``ids[k]``. The
    attributes every part has are kept. Written a chunk at a time: memory holds the
    parts and one chunk, never a merged copy. With ``load``, part k's points are
    ``load(k)``, called as it is written, and ``parts`` a sample of each that plans
    the file (its attributes and extent): memory then holds one part as loaded.
    With ``labels``, each point's ``tree`` and ground class are ``labels`` of its
    coordinates in the frame, (M, 3) local to ``offset`` (:func:`write_las_parts`).

    Raises
    ------
    InvalidInput
        A path not ending in ``.las`` or ``.laz``, or in a missing folder.
    """
    path = Path(path)
    if path.suffix.lower() not in (".las", ".laz"):
        raise InvalidInput(
            f"Cannot write {path.name} as one merged cloud: give it a .laz or .las name."
        )
    if not path.parent.is_dir():
        raise InvalidInput(
            f"Cannot write {path}: the folder {path.parent} does not exist."
        )
    compress = path.suffix.lower() == ".laz"
    write_atomic(
        path,
        lambda tmp: write_las_parts(
            tmp,
            parts,
            moves,
            offset,
            ids,
            compress=compress,
            load=load,
            labels=labels,
        ),
    )


__all__ = [
    "MAX_COORD_M",
    "PathLike",
    "Reader",
    "check_readable",
    "describe",
    "format_description",
    "get_reader",
    "read",
    "read_overview",
    "read_region",
    "supported_extensions",
    "writable_extensions",
    "write",
    "write_merged",
]
