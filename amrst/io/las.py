"""LAS and LAZ files through laspy (LAZ via lazrs); private to amrst.io.

Coordinates are read from the raw integers and the header scales, with the header
offsets as the cloud offset, so georeferenced files keep their precision. On write,
attributes named like a standard LAS dimension go there; every other attribute goes
into an extra-bytes dimension. A standard-named attribute whose values the standard
field cannot hold (e.g. a float intensity of 0.37) is also stored exactly in an
extra dimension ``amrst_<name>``, which the reader maps back.

laspy trusts a file's header, so the reader checks the fixed header with
``struct`` first (a corrupt one can make laspy loop for minutes), and refuses
points that mostly lie outside the header's bounds (garbage point records).
"""

from __future__ import annotations

import functools
import logging
import math
import struct
from typing import TYPE_CHECKING, Any, NamedTuple

import numpy as np

from amrst.errors import InvalidInput
from amrst.io.common import RawCloud, flat_attributes, storable

if TYPE_CHECKING:
    from collections.abc import Mapping
    from pathlib import Path

    from amrst.types import Cloud

logger = logging.getLogger(__name__)

_PREFIX = "amrst_"
_CANDIDATE_FORMATS = (0, 1, 2, 3, 6, 7, 8)
_DEFAULT_SCALE_M = 1e-4  # 0.1 mm: keeps millimetres after any transform
_INT32_MAX = 2**31 - 1
_SKIP_VLRS = {("LASF_Spec", 4), ("laszip encoded", 22204)}  # laspy writes these
_HEADER_MIN = 227  # bytes of the LAS 1.0-1.2 public header; 1.3 and 1.4 add more
_VLR_HEADER = 54  # bytes of a variable-length record's header
_EVLR_HEADER = 60  # bytes of an extended VLR's header (LAS 1.4, after the points)
_BOUNDS_SLACK = 0.1  # header bounds may be this share of their size too tight
_BOUNDS_STEPS = 3  # ... plus this many scale steps of rounding


class _FixedHeader(NamedTuple):
    """The fields of the public header checked before laspy reads the file."""

    scales: np.ndarray  # (3,) float64
    mins: np.ndarray  # (3,) float64, world coordinates
    maxs: np.ndarray  # (3,) float64


@functools.cache
def _dimension_names(point_format: int) -> frozenset[str]:
    import laspy

    names = laspy.PointFormat(point_format).dimension_names
    return frozenset(names) - {"X", "Y", "Z"}


def _all_standard_names() -> frozenset[str]:
    return frozenset().union(*(_dimension_names(i) for i in range(11)))


def read_las(path: Path) -> RawCloud:
    """Read a LAS/LAZ file: coordinates, every non-zero dimension, header details."""
    import laspy

    fixed = _check_header(path)  # before laspy: a corrupt header can make it loop
    with laspy.open(path) as reader:
        _check_size(reader.header, path)
        las = reader.read()
    header = las.header
    scales = np.asarray(header.scales, dtype=np.float64)
    raw = (las.X, las.Y, las.Z)
    xyz = np.column_stack([np.asarray(v) * s for v, s in zip(raw, scales, strict=True)])
    _check_bounds(xyz + np.asarray(header.offsets, np.float64), fixed, path)
    attributes: dict[str, np.ndarray] = {}
    for dim in header.point_format.dimensions:
        if dim.name in ("X", "Y", "Z"):
            continue
        values = np.array(las[dim.name])
        if dim.is_standard and not values.any():
            continue  # all-zero flags and fields carry nothing; LAS writes them as 0
        attributes[dim.name] = values
    for name in [n for n in attributes if n.startswith(_PREFIX)]:
        if name[len(_PREFIX) :] in _all_standard_names():
            attributes[name[len(_PREFIX) :]] = attributes.pop(name)
    meta = {
        "las_version": str(header.version),
        "las_point_format": int(header.point_format.id),
        "las_scales": tuple(float(s) for s in scales),
        "las_offsets": tuple(float(o) for o in header.offsets),
        "las_vlrs": tuple(
            (v.user_id, v.record_id, v.description, bytes(v.record_data_bytes()))
            for v in header.vlrs
            if (v.user_id, v.record_id) not in _SKIP_VLRS
        ),
    }
    return RawCloud(xyz, np.asarray(header.offsets, np.float64), attributes, meta)


def _check_header(path: Path) -> _FixedHeader:
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
    header_size, point_start, n_vlrs = struct.unpack_from("<HII", head, 94)
    values = np.array(struct.unpack_from("<12d", head, 131))
    scales, offsets = values[0:3], values[3:6]
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
    for axis, scale, offset in zip("xyz", scales, offsets, strict=True):
        if not (math.isfinite(scale) and scale > 0):
            consequence = (
                f", so every {axis} coordinate would be 0" if scale == 0 else ""
            )
            raise InvalidInput(
                f"{corrupt} the header scale factor is {scale:g} for {axis}"
                f"{consequence}; it must be a positive number such as 0.001. "
                "Export the file again."
            )
        if not math.isfinite(offset):
            raise InvalidInput(
                f"{corrupt} the header offset is {offset:g} for {axis}; it must be "
                "a finite number. Export the file again."
            )
    if head[104] & 0xC0 == 0x80:  # LAZ: bit 7 of the point format id
        _check_laz_count(path, head)
    return _FixedHeader(scales, values[7:12:2], values[6:12:2])


def _check_laz_count(path: Path, head: bytes) -> None:
    """Refuse a LAZ whose header announces more points than its chunks can hold.

    LASzip stores points in chunks of a fixed size (in its VLR) and lists the
    chunks in a table at the end. laszip decompresses the announced count
    regardless, allocating it first: 2**28 announced points take 5 GB and
    many seconds before failing. Files with variable chunks or without a chunk
    table are left to laspy.
    """
    header_size, point_start, n_vlrs = struct.unpack_from("<HII", head, 94)
    legacy = head[25] < 4 or len(head) < 255  # LAS 1.4 counts points in 64 bits
    (n_points,) = struct.unpack_from(
        "<I" if legacy else "<Q", head, 107 if legacy else 247
    )
    chunk_size = None
    with open(path, "rb") as f:
        pos = header_size
        for _ in range(n_vlrs):
            f.seek(pos)
            vlr = f.read(_VLR_HEADER)
            if len(vlr) < _VLR_HEADER or pos + _VLR_HEADER > point_start:
                return
            record_id, length = struct.unpack_from("<HH", vlr, 18)
            if vlr[2:18].rstrip(b"\0") == b"laszip encoded" and record_id == 22204:
                data = f.read(length)
                if len(data) >= 16:
                    (chunk_size,) = struct.unpack_from("<I", data, 12)
                break
            pos += _VLR_HEADER + length
        if chunk_size is None or chunk_size == 0xFFFFFFFF:  # variable-size chunks
            return
        f.seek(point_start)
        raw = f.read(8)
        (table_start,) = struct.unpack("<q", raw) if len(raw) == 8 else (-1,)
        if not point_start < table_start <= path.stat().st_size - 8:
            return
        f.seek(table_start)
        _, n_chunks = struct.unpack("<II", f.read(8))
    if n_points > n_chunks * chunk_size:
        raise InvalidInput(
            f"{path}: corrupt LAZ header: it announces {n_points:,} points but the "
            f"file's {n_chunks:,} compressed chunks hold at most "
            f"{n_chunks * chunk_size:,}. The file is corrupt or truncated; "
            "copy or export it again."
        )


def _check_bounds(world: np.ndarray, fixed: _FixedHeader, path: Path) -> None:
    """Refuse points that mostly lie outside the header's bounding box.

    Garbage point records decode to coordinates spread over hundreds of km; a
    valid file's points lie inside the box its header gives. Axes whose bounds
    are unusable (not finite, inverted, or both 0 as some writers leave them)
    are not checked.
    """
    lo, hi = fixed.mins, fixed.maxs
    usable = np.isfinite(lo) & np.isfinite(hi) & (hi >= lo) & ((lo != 0) | (hi != 0))
    if len(world) == 0 or not usable.any():
        return
    margin = _BOUNDS_SLACK * (hi - lo) + _BOUNDS_STEPS * fixed.scales
    with np.errstate(invalid="ignore", over="ignore"):
        outside = (world < lo - margin) | (world > hi + margin)
    share = np.where(usable, outside.mean(axis=0), 0.0)
    axis = int(np.argmax(share))
    if share[axis] > 0.5:
        raise InvalidInput(
            f"{path}: {share[axis]:.0%} of the points lie outside the bounds its "
            f"header gives for {'xyz'[axis]} ({lo[axis]:.3f} to {hi[axis]:.3f}): "
            "the points disagree with the header bounds, so the file is corrupt. "
            "Export it again."
        )


def _check_size(header: Any, path: Path) -> None:
    """Uncompressed LAS: the file must hold all the points the header announces."""
    if header.are_points_compressed:
        return
    size = header.point_format.size
    found = (path.stat().st_size - header.offset_to_point_data) // size
    if found < header.point_count:
        raise InvalidInput(
            f"{path} is truncated: it holds {max(found, 0)} of the "
            f"{header.point_count} points its header announces. "
            "Copy or export it again."
        )


def _choose_format(names: set[str], meta: Mapping[str, Any]) -> int:
    """Pick the point format holding most standard-named attributes (file's first)."""
    wanted = names & _all_standard_names()
    preferred: Any = meta.get("las_point_format")
    candidates = list(_CANDIDATE_FORMATS)
    if preferred in range(11):
        candidates.insert(0, int(preferred))
    scored = [
        (len(wanted & _dimension_names(fmt)), -i, fmt)
        for i, fmt in enumerate(candidates)
    ]
    return max(scored)[2]


def _quantize(cloud: Cloud) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Scales (3,), offsets (3,) and the (N, 3) int32 coordinates for the header."""
    scales = np.minimum(
        np.asarray(cloud.meta.get("las_scales", [_DEFAULT_SCALE_M] * 3), float),
        _DEFAULT_SCALE_M,
    )
    offsets = np.round(cloud.offset)
    if len(cloud) == 0:
        return scales, offsets, np.zeros((0, 3), np.int32)
    lo, hi = cloud.xyz.min(axis=0), cloud.xyz.max(axis=0)
    if np.any(
        np.maximum(abs(lo), abs(hi)) + abs(cloud.offset - offsets) > _INT32_MAX * scales
    ):
        offsets = np.round(cloud.offset + (lo + hi) / 2)  # re-centre on the points
    reach = np.maximum(
        abs(lo + cloud.offset - offsets), abs(hi + cloud.offset - offsets)
    )
    too_fine = reach > 0.99 * _INT32_MAX * scales
    if too_fine.any():
        coarse = 10.0 ** np.ceil(np.log10(reach / (0.99 * _INT32_MAX)))
        scales = np.where(too_fine, coarse, scales)
        logger.warning(
            "The cloud spans %s m; LAS scale coarsened to %s m to fit 32-bit integers.",
            np.round(hi - lo).tolist(),
            scales.tolist(),
        )
    local = cloud.xyz + (cloud.offset - offsets)
    return scales, offsets, np.round(local / scales).astype(np.int32)


def _fit(dim: Any, values: np.ndarray) -> tuple[np.ndarray, bool]:
    """Values cast for a standard dimension, and whether the cast kept them exactly."""
    data = np.asarray(values, dtype=np.float64)
    if dim.kind.name == "FloatingPoint":
        return data, bool(np.array_equal(data, values, equal_nan=True))
    exact = bool(
        np.all(np.isfinite(data))
        and np.all(data == np.round(data))
        and np.all((data >= dim.min) & (data <= dim.max))
    )
    fitted = np.clip(np.round(np.nan_to_num(data)), dim.min, dim.max)
    return fitted.astype(dim.dtype or np.uint8), exact


def _split(cloud: Cloud, point_format: int) -> tuple[dict[str, Any], dict[str, Any]]:
    """Attributes for standard dimensions and for extra dimensions."""
    import laspy

    fmt = laspy.PointFormat(point_format)
    standard: dict[str, np.ndarray] = {}
    extra: dict[str, np.ndarray] = {}
    for name, values in flat_attributes(cloud).items():
        if name in _dimension_names(point_format):
            standard[name], exact = _fit(fmt.dimension_by_name(name), values)
            if exact:
                continue
            name = _PREFIX + name
        value = storable(values, allow_int64=True, name=name)
        if value is not None:
            if len(name) > 32:
                logger.warning(
                    "LAS extra dimension name %r cut to 32 characters.", name
                )
            extra[name[:32]] = value
    return standard, extra


def write_las(
    path: Path, cloud: Cloud, *, binary: bool = True, compress: bool = False
) -> None:
    """Write LAS (or LAZ when ``compress``) keeping every attribute; see module docs."""
    import laspy

    point_format = _choose_format(set(flat_attributes(cloud)), cloud.meta)
    standard, extra = _split(cloud, point_format)
    version = "1.4" if cloud.meta.get("las_version") == "1.4" else None
    header = laspy.LasHeader(point_format=point_format, version=version)
    header.scales, header.offsets, ints = _quantize(cloud)
    header.add_extra_dims(
        [laspy.ExtraBytesParams(name, v.dtype.str[1:]) for name, v in extra.items()]
    )
    for user_id, record_id, description, data in cloud.meta.get("las_vlrs", ()):
        header.vlrs.append(laspy.VLR(user_id, record_id, description, data))
    las = laspy.LasData(
        header, points=laspy.ScaleAwarePointRecord.zeros(len(cloud), header=header)
    )
    las.X, las.Y, las.Z = ints[:, 0], ints[:, 1], ints[:, 2]
    for name, values in {**standard, **extra}.items():
        las[name] = values
    with open(path, "wb") as f:
        las.write(f, do_compress=compress)
