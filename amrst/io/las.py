"""Reading LAS, LAZ and COPC files through laspy; private to amrst.io.

Coordinates are read from the raw integers and the header scales, with the header
offsets as the cloud offset, so georeferenced files keep their precision. Extra
dimensions ``amrst_<name>`` written by :mod:`amrst.io.las_write` map back to
their standard names.

laspy trusts a file's header, so the reader checks the fixed header with
``struct`` first (a corrupt one can make laspy loop for minutes), and refuses
points that mostly lie outside the header's bounds and spread over the whole
integer range (garbage point records). Header quirks that leave the points intact
(bounds in raw units or simply wrong, a count too low) are read with a one-line
warning.
"""

from __future__ import annotations

import contextlib
import functools
import logging
import struct
import tempfile
from pathlib import Path
from typing import TYPE_CHECKING, Any, NamedTuple

import numpy as np

from amrst.errors import Cancelled, InvalidInput
from amrst.io.common import RawCloud, shorten
from amrst.io.laz import (
    check_laz_count,
    check_laz_vlr,
    decompress_in_child,
    is_panic,
    laz_info,
    lazrs_backends,
    needs_laszip,
    quiet_decoders,
)
from amrst.progress import NULL_REPORTER, Reporter
from amrst.types import MAX_COORD_M

if TYPE_CHECKING:
    from collections.abc import Iterator

    from amrst.io.laz import LazInfo

logger = logging.getLogger(__name__)

PREFIX = "amrst_"
_SKIP_VLRS = {("LASF_Spec", 4), ("laszip encoded", 22204)}  # laspy writes these
_HEADER_MIN = 227  # bytes of the LAS 1.0-1.2 public header; 1.3 and 1.4 add more
_VLR_HEADER = 54  # bytes of a variable-length record's header
_LAST_POINT_FORMAT = 10  # LAS 1.4 defines point formats 0 to 10
_EVLR_HEADER = 60  # bytes of an extended VLR's header (LAS 1.4, after the points)
_BOUNDS_SLACK = 0.1  # header bounds may be this share of their size too tight
_BOUNDS_STEPS = 3  # ... plus this many scale steps of rounding
_COMPACT_SPAN = 2.0**32 / 64  # raw integer span of intact points (garbage: ~2**32)
_MIN_SCALE = 1e-9  # m per stored unit: finer than any scanner resolves
_MAX_SCALE = 1.0  # m per stored unit: coarser than any scan of a tree


class FixedHeader(NamedTuple):
    """The fields of the public header checked before laspy reads the file."""

    scales: np.ndarray  # (3,) float64
    offsets: np.ndarray  # (3,) float64
    mins: np.ndarray  # (3,) float64, world coordinates
    maxs: np.ndarray  # (3,) float64
    laz: LazInfo | None  # the LASzip VLR of a LAZ file


@functools.cache
def dimension_names(point_format: int) -> frozenset[str]:
    """Return the standard dimension names of a LAS point format, without X, Y, Z."""
    import laspy

    names = laspy.PointFormat(point_format).dimension_names
    return frozenset(names) - {"X", "Y", "Z"}


def all_standard_names() -> frozenset[str]:
    """Return the standard dimension names of every LAS point format (0-10)."""
    return frozenset().union(
        *(dimension_names(i) for i in range(_LAST_POINT_FORMAT + 1))
    )


# Points decoded per step of a read, so a Cancel (the reporter's check point between
# steps) stops a read promptly; lazrs holds the GIL while it decodes a step, so a
# small step also keeps the app's window responsive.
CHUNK_POINTS = 100_000


def read_las(path: Path, reporter: Reporter = NULL_REPORTER) -> RawCloud:
    """Read a LAS/LAZ/COPC file: coordinates, every non-zero dimension, header details.

    The points are decoded ``CHUNK_POINTS`` at a time, with ``reporter``'s
    progress and cancel check between chunks (:class:`amrst.errors.Cancelled`:
    nothing of the file is kept).
    """
    fixed = check_header(path)  # before laspy: a corrupt header can make it loop
    return las_to_raw(decode(path, fixed, reporter), fixed, path)


def las_to_raw(las: Any, fixed: FixedHeader, path: Path) -> RawCloud:
    """Turn laspy's LasData (all or part of ``path``) into a RawCloud."""
    header = las.header
    scales = np.asarray(header.scales, dtype=np.float64)
    raw = (las.X, las.Y, las.Z)
    xyz = np.column_stack([np.asarray(v) * s for v, s in zip(raw, scales, strict=True)])
    world = xyz + np.asarray(header.offsets, np.float64)
    _check_bounds(world, np.column_stack(raw), fixed, path)
    attributes: dict[str, np.ndarray] = {}
    for dim in header.point_format.dimensions:
        if dim.name in ("X", "Y", "Z"):
            continue
        values = np.array(las[dim.name])
        if dim.is_standard and not values.any():
            continue  # all-zero flags and fields carry nothing; LAS writes them as 0
        attributes[dim.name] = values
    for name in [n for n in attributes if n.startswith(PREFIX)]:
        if name[len(PREFIX) :] in all_standard_names():
            attributes[name[len(PREFIX) :]] = attributes.pop(name)
    meta = {
        "las_version": str(header.version),
        "las_point_format": int(header.point_format.id),
        "las_scales": tuple(float(s) for s in scales),
        "las_offsets": tuple(float(o) for o in header.offsets),
        "las_vlrs": tuple(
            (v.user_id, v.record_id, v.description, bytes(v.record_data_bytes()))
            for v in header.vlrs
            if (v.user_id, v.record_id) not in _SKIP_VLRS
            and v.user_id.rstrip("\0") != "copc"  # the octree layout of this file
        ),
    }
    if fixed.laz is not None:
        meta["laz_compressor"] = fixed.laz.describe()
    return RawCloud(xyz, np.asarray(header.offsets, np.float64), attributes, meta)


def decode(path: Path, fixed: FixedHeader, reporter: Reporter = NULL_REPORTER) -> Any:
    """Return laspy's LasData for the file, decoded as its LASzip variant needs.

    Files lazrs cannot read are decompressed by laszip in a child process (it
    crashes on truncated files). A decoder failure or panic becomes one InvalidInput.
    """
    if needs_laszip(path, fixed.laz):
        with tempfile.TemporaryDirectory(prefix="amrst-laz-") as folder:
            plain = Path(folder) / "points.las"
            decompress_in_child(path, plain)
            las = _open_and_read(plain, reporter)
            las.header.vlrs = [v for v in las.header.vlrs if v.record_id != 22204]
            return las
    try:
        return _open_and_read(path, reporter)
    except (InvalidInput, Cancelled):
        raise
    except BaseException as exc:
        if not (isinstance(exc, Exception) or is_panic(exc)):
            raise  # KeyboardInterrupt, SystemExit
        raise InvalidInput(
            f"{path} is corrupt or truncated: its points cannot be decoded "
            f"({shorten(str(exc) or type(exc).__name__, 100)}). Copy or export it "
            "again."
        ) from exc


def _open_and_read(path: Path, reporter: Reporter = NULL_REPORTER) -> Any:
    import laspy

    reporter.check_cancelled()
    with quiet_decoders():  # not around our own warnings: stderr is muted there
        reader = laspy.open(path, laz_backend=lazrs_backends())
    with reader:
        _check_size(reader.header, path)
        header = reader.header
        n = int(header.point_count)
        # One array filled chunk by chunk (no list of chunks to concatenate: the
        # peak stays one copy of the points).
        points = np.empty(n, dtype=header.point_format.dtype())
        done = 0
        while done < n:
            reporter.check_cancelled()
            with quiet_decoders():
                chunk = reader.read_points(min(CHUNK_POINTS, n - done))
            if len(chunk) == 0:
                break
            points[done : done + len(chunk)] = chunk.array
            done += len(chunk)
            reporter.progress(done / n, f"{done:,} of {n:,} points read")
        reporter.check_cancelled()
        record = laspy.ScaleAwarePointRecord(
            points[:done], header.point_format, header.scales, header.offsets
        )
        return laspy.LasData(header=header, points=record)


@contextlib.contextmanager
def open_points(path: Path, fixed: FixedHeader) -> Iterator[Any]:
    """Open ``path`` for streaming with laspy (a LasReader), decoded as it needs.

    Files that need laszip are first decompressed (in a child process) into a
    temporary uncompressed LAS, which is streamed instead.
    """
    import laspy

    with contextlib.ExitStack() as stack:
        if needs_laszip(path, fixed.laz):
            folder = stack.enter_context(
                tempfile.TemporaryDirectory(prefix="amrst-laz-")
            )
            plain = Path(folder) / "points.las"
            decompress_in_child(path, plain)
            path = plain
        with quiet_decoders():  # the caller quiets each read it makes
            reader = stack.enter_context(laspy.open(path, laz_backend=lazrs_backends()))
        _check_size(reader.header, path)
        yield reader


def check_header(path: Path) -> FixedHeader:
    """Refuse a file whose public header is not LAS or is corrupt, without laspy.

    laspy trusts the header: a huge number of (extended) variable-length records
    makes it read past the end of the file for minutes, and a scale of 0 turns
    every coordinate into 0. These checks read a few hundred bytes.
    """
    size = path.stat().st_size
    with open(path, "rb") as f:
        head = f.read(375)  # the LAS 1.4 header; 1.0-1.2 use the first 227 bytes
    if len(head) < _HEADER_MIN:
        raise InvalidInput(
            f"{path} is too short to be a LAS/LAZ file ({size} bytes; the header "
            f"alone takes {_HEADER_MIN}): it is truncated or not a LAS file. "
            "Copy or export it again."
        )
    if head[:4] != b"LASF":
        raise InvalidInput(
            f"{path} is not a LAS/LAZ file (it does not start with 'LASF'). "
            "Export it again as LAS/LAZ, or give it its real extension."
        )
    _check_layout(path, head, size)
    point_format = head[104] & 0x7F  # bit 7 marks compressed points (LAZ)
    if point_format > _LAST_POINT_FORMAT:
        raise InvalidInput(
            f"{path}: corrupt LAS header: point format {point_format} is not a LAS "
            f"point format (0 to {_LAST_POINT_FORMAT}). Export the file again."
        )
    values = np.array(struct.unpack_from("<12d", head, 131))
    scales, offsets = values[0:3], values[3:6]
    _check_scales(path, scales, offsets)
    laz = None
    if head[104] & 0x80:  # LAZ
        laz = laz_info(path, head)
        legacy = head[25] < 4 or len(head) < 255  # LAS 1.4 counts points in 64 bits
        (n_points,) = struct.unpack_from(
            "<I" if legacy else "<Q", head, 107 if legacy else 247
        )
        if laz is not None:
            record_length = struct.unpack_from("<H", head, 105)[0]
            check_laz_vlr(path, laz, record_length, n_points)
            check_laz_count(path, n_points, laz, record_length)
    return FixedHeader(scales, offsets, values[7:12:2], values[6:12:2], laz)


def _check_layout(path: Path, head: bytes, size: int) -> None:
    """Refuse a header whose header size, records and point start do not fit the file."""
    header_size, point_start, n_vlrs = struct.unpack_from("<HII", head, 94)
    corrupt = f"{path}: corrupt LAS header:"
    if not _HEADER_MIN <= header_size <= size:
        raise InvalidInput(
            f"{corrupt} it gives a header size of {header_size} bytes (at least "
            f"{_HEADER_MIN} and at most the file's {size} bytes are possible). "
            "Export the file again."
        )
    if point_start < header_size + _VLR_HEADER * n_vlrs:
        raise InvalidInput(
            f"{corrupt} it announces {n_vlrs:,} variable-length records that cannot "
            f"fit between the header ({header_size} bytes) and the points (byte "
            f"{point_start:,}). Export the file again."
        )
    if point_start > size:
        raise InvalidInput(
            f"{corrupt} its points would start at byte {point_start:,}, after the "
            f"end of the file ({size:,} bytes): it is truncated or corrupt. "
            "Copy or export it again."
        )
    if head[25] >= 4 and len(head) >= 247:  # LAS 1.4 (as laspy reads it): EVLRs
        evlr_start, n_evlrs = struct.unpack_from("<QI", head, 235)
        if n_evlrs and not point_start <= evlr_start <= size - _EVLR_HEADER * n_evlrs:
            raise InvalidInput(
                f"{corrupt} it announces {n_evlrs:,} extended variable-length "
                f"records from byte {evlr_start:,} that cannot fit in the file "
                f"({size:,} bytes). Export the file again."
            )


def _check_scales(path: Path, scales: np.ndarray, offsets: np.ndarray) -> None:
    """Refuse scale factors and offsets that no scan's header holds.

    A scale factor is the size of one stored unit: between a nanometre and a
    metre for any laser scan (scanners store millimetres or finer). An offset is
    a coordinate, so it lies within ``MAX_COORD_M`` like every coordinate read.
    """
    corrupt = f"{path}: corrupt LAS header:"
    for axis, scale, offset in zip("xyz", scales, offsets, strict=True):
        if not _MIN_SCALE <= scale <= _MAX_SCALE:  # False for NaN too
            consequence = (
                f", so every {axis} coordinate would be 0" if scale == 0 else ""
            )
            raise InvalidInput(
                f"{corrupt} the header scale factor is {scale:g} for {axis}"
                f"{consequence}; it must lie between {_MIN_SCALE:g} and "
                f"{_MAX_SCALE:g} (metres per stored unit), such as 0.001. "
                "Export the file again."
            )
        if not abs(offset) <= MAX_COORD_M:  # False for NaN too
            raise InvalidInput(
                f"{corrupt} the header offset is {offset:g} for {axis}; it must be "
                f"a coordinate within {MAX_COORD_M:g} m. Export the file again."
            )


def _check_bounds(
    world: np.ndarray, ints: np.ndarray, fixed: FixedHeader, path: Path
) -> None:
    """Refuse garbage point records; report header bounds that are merely wrong.

    Garbage point records decode to coordinates spread over the whole 32-bit
    integer range (hundreds of km); a valid file's points lie inside the box its
    header gives. When most points lie outside it, the points are still read
    (with a warning) if the box is the points' box in raw integer units (as some
    LAS 1.3 writers store it) or if the points are compact (intact), else the file
    is refused. Axes whose bounds are unusable (not finite, inverted, or both 0
    as some writers leave them) are not checked.
    """
    share = _outside_share(world, fixed.mins, fixed.maxs, fixed.scales)
    axis = int(np.argmax(share))
    if share[axis] <= 0.5:
        if share[axis] > 0:
            logger.warning(
                "%s: %.1f%% of the points lie outside the bounds its header gives for "
                "%s (%.3f to %.3f); they were read as stored. If points look out of "
                "place, export the file again.",
                path.name,
                100 * share[axis],
                "xyz"[axis],
                fixed.mins[axis],
                fixed.maxs[axis],
            )
        return
    lo, hi = fixed.mins, fixed.maxs
    as_raw = _outside_share(
        world, lo * fixed.scales + fixed.offsets, hi * fixed.scales + fixed.offsets,
        fixed.scales,
    )  # fmt: skip
    said = f"{lo[axis]:.3f} to {hi[axis]:.3f}"
    if as_raw.max() <= 0.5:
        logger.warning(
            "%s: the header bounds are in raw integer units, not metres (%s for "
            "%s); the points are intact and were read as stored.",
            path.name,
            said,
            "xyz"[axis],
        )
        return
    span = ints.max(axis=0).astype(np.float64) - ints.min(axis=0)
    if len(ints) and np.all(span < _COMPACT_SPAN):
        logger.warning(
            "%s: the header bounds (%s for %s) do not contain %.0f%% of the "
            "points, but the points are compact and were read as stored; the "
            "writer left wrong bounds.",
            path.name,
            said,
            "xyz"[axis],
            100 * share[axis],
        )
        return
    raise InvalidInput(
        f"{path}: {share[axis]:.0%} of the points lie outside the bounds its "
        f"header gives for {'xyz'[axis]} ({said}) and spread over the whole "
        "integer range: the points disagree with the header bounds, so the file "
        "is corrupt. Export it again."
    )


def _outside_share(
    world: np.ndarray, lo: np.ndarray, hi: np.ndarray, scales: np.ndarray
) -> np.ndarray:
    """(3,) share of the points outside [lo, hi] (with slack) per usable axis."""
    usable = np.isfinite(lo) & np.isfinite(hi) & (hi >= lo) & ((lo != 0) | (hi != 0))
    if len(world) == 0:
        return np.zeros(3)
    margin = _BOUNDS_SLACK * (hi - lo) + _BOUNDS_STEPS * scales
    with np.errstate(invalid="ignore", over="ignore"):
        outside = (world < lo - margin) | (world > hi + margin)
    return np.where(usable, outside.mean(axis=0), 0.0)


def _check_size(header: Any, path: Path) -> None:
    """Uncompressed LAS: the file must hold the announced points; more is reported."""
    if header.are_points_compressed:
        return
    size = header.point_format.size
    end = path.stat().st_size
    for start in (
        getattr(header, "start_of_waveform_data_packet_record", 0),
        header.start_of_first_evlr if getattr(header, "number_of_evlrs", 0) else 0,
    ):
        if header.offset_to_point_data < start < end:
            end = start  # waveforms or extended VLRs follow the points
    found = (end - header.offset_to_point_data) // size
    if found < header.point_count:
        raise InvalidInput(
            f"{path} is truncated: it holds {max(found, 0)} of the "
            f"{header.point_count} points its header announces. "
            "Copy or export it again."
        )
    if found > header.point_count:
        logger.warning(
            "%s: the LAS header announces %d points but the file holds %d; only "
            "the announced %d were read. If points are missing, export the file "
            "again.",
            path.name,
            header.point_count,
            found,
            header.point_count,
        )
