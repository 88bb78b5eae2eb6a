"""PCD (Point Cloud Library) files: ascii, binary and binary_compressed (LZF).

Every field is kept; a packed ``rgb``/``rgba`` field is unpacked into
``red``/``green``/``blue`` (uint8) and packed again on write (private to amrst.io).
"""

from __future__ import annotations

import os
import struct
from typing import TYPE_CHECKING, BinaryIO, NamedTuple, cast

import numpy as np

from amrst.errors import InvalidInput
from amrst.io.common import (
    RawCloud,
    clean_name,
    coordinate_columns,
    count_data_lines,
    format_rows,
    needs_double,
    number_format,
    quote,
    shorten,
    storable,
    warn_undercount,
)
from amrst.io.text import parse_numbers, stream_rows

if TYPE_CHECKING:
    from pathlib import Path

    from amrst.types import Cloud

_KINDS = {"F": "f", "I": "i", "U": "u"}
_CODES = {"f2", "f4", "f8", "i1", "i2", "i4", "i8", "u1", "u2", "u4", "u8"}
_MAX_HEADER_LINES = 100
_LZF_MAX_RATIO = 88  # a 3-byte LZF back reference yields at most 264 bytes


class _Header(NamedTuple):
    fields: list[tuple[str, str, int]]  # (name, numpy code, count)
    points: int
    data: str  # ascii | binary | binary_compressed
    n_lines: int  # header lines, so errors can name the file's line


def _parse_header(f: BinaryIO, path: Path) -> _Header:
    keys: dict[str, list[str]] = {}
    for n_lines in range(1, _MAX_HEADER_LINES + 1):
        line = f.readline()
        if not line:
            break
        words = line.decode("ascii", errors="replace").split()
        if not words or words[0].startswith("#"):
            continue
        keys[words[0].upper()] = words[1:]
        if words[0].upper() == "DATA":
            return _make_header(keys, n_lines, path)
    raise InvalidInput(
        f"{path} is not a PCD file (no 'DATA' line in its header). Give it its "
        "real extension, or re-save the file with PCL."
    )


def _make_header(keys: dict[str, list[str]], n_lines: int, path: Path) -> _Header:
    try:
        names = keys["FIELDS"]
        sizes = [int(s) for s in keys["SIZE"]]
        kinds = [_KINDS[t.upper()] for t in keys["TYPE"]]
        counts = [int(c) for c in keys.get("COUNT", ["1"] * len(names))]
        points = int(keys.get("POINTS", [0])[0]) or int(keys["WIDTH"][0]) * int(
            keys.get("HEIGHT", ["1"])[0]
        )
    except (KeyError, ValueError, IndexError) as exc:
        raise InvalidInput(
            f"{path}: the PCD header is incomplete or malformed ({shorten(repr(exc))} "
            "missing or wrong in FIELDS/SIZE/TYPE/COUNT/POINTS). Re-save the file "
            "with PCL."
        ) from exc
    if points < 0 or min(counts, default=1) < 1:
        raise InvalidInput(
            f"{path}: the PCD header gives a negative number of points or a COUNT "
            "below 1; the file is corrupt. Re-save the file with PCL."
        )
    if not len(names) == len(sizes) == len(kinds) == len(counts):
        raise InvalidInput(
            f"{path}: FIELDS, SIZE, TYPE and COUNT differ in length; the header is "
            "corrupt. Re-save the file with PCL."
        )
    fields = [
        (name if name != "_" else f"_pad{i}", f"{k}{s}", c)
        for i, (name, k, s, c) in enumerate(
            zip(names, kinds, sizes, counts, strict=True)
        )
    ]
    for name, code, _ in fields:
        if code not in _CODES:
            raise InvalidInput(
                f"{path}: field {quote(name, 40)} has TYPE {code[0].upper()} with "
                f"SIZE {code[1:]}, which PCD does not define (F: 4 or 8; "
                "I and U: 1, 2, 4 or 8). The header is corrupt; re-save the file."
            )
    return _Header(fields, points, keys["DATA"][0].lower(), n_lines)


def _lzf_decompress(data: bytes, expected: int) -> bytes:
    """Decompress LZF (liblzf format, as PCL uses for binary_compressed).

    The compiled decoder of ``python-lzf`` when installed (far faster), else a
    pure-Python one; both stop at ``expected`` bytes.
    """
    try:
        import lzf  # type: ignore[import-not-found]
    except ImportError:
        return _lzf_decompress_python(data, expected)
    out = lzf.decompress(data, max(expected, 1)) if data else b""
    if out is None or len(out) != expected:  # None: more than expected
        found = "more" if out is None else f"{len(out)}"
        raise ValueError(f"LZF data decompressed to {found} bytes, not {expected}")
    return bytes(out)


def _lzf_decompress_python(data: bytes, expected: int) -> bytes:
    out = bytearray()
    i, n = 0, len(data)
    while i < n and len(out) <= expected:
        ctrl = data[i]
        i += 1
        if ctrl < 32:  # a literal run of ctrl + 1 bytes
            out += data[i : i + ctrl + 1]
            i += ctrl + 1
            continue
        length = ctrl >> 5
        if length == 7:
            length += data[i] if i < n else 0
            i += 1
        ref = len(out) - ((ctrl & 0x1F) << 8) - (data[i] if i < n else 0) - 1
        i += 1
        length += 2
        if ref < 0:
            raise ValueError("corrupt LZF data (back reference before start)")
        if ref + length <= len(out):
            out += out[ref : ref + length]
        else:  # overlapping copy: repeats a short pattern
            for k in range(length):
                out.append(out[ref + k])
    if len(out) != expected:
        raise ValueError(f"LZF data decompressed to {len(out)} bytes, not {expected}")
    return bytes(out)


def _ascii_rows(header: _Header, f: BinaryIO, path: Path) -> np.ndarray:
    """Read the DATA ascii rows a line at a time; the text whole on an error.

    ``f`` stands just after the header. Every refusal comes from the whole-text path,
    which names the line at fault.
    """
    n, start = header.points, f.tell()
    width = sum(c for _, _, c in header.fields)
    flat, extra = stream_rows(f, n, width)
    if flat is None or len(flat) < n:
        f.seek(start)
        text = f.read().decode("ascii", errors="replace")
        flat = parse_numbers(text, width, None, header.n_lines + 1, path, max_rows=n)
        _check_count(len(flat), n, path)
        extra = count_data_lines(text, n) - n
    if extra > 0:
        warn_undercount(path, "PCD", n, extra)
    return flat


def _columns(header: _Header, f: BinaryIO, path: Path) -> dict[str, np.ndarray]:
    n = header.points
    if header.data == "ascii":
        flat = _ascii_rows(header, f, path)
        out, col = {}, 0
        for name, code, count in header.fields:
            out[name] = _squeeze(flat[:, col : col + count].astype(code))
            col += count
        return out
    if header.data == "binary":
        dtype = np.dtype([(name, "<" + code, (c,)) for name, code, c in header.fields])
        _check_room(n, dtype.itemsize, f, path)
        left = os.fstat(f.fileno()).st_size - f.tell()
        raw = f.read(n * dtype.itemsize)
        _check_count(len(raw) // max(dtype.itemsize, 1), n, path)
        extra = (left - n * dtype.itemsize) // max(dtype.itemsize, 1)
        if extra > 0:
            warn_undercount(path, "PCD", n, extra)
        records = np.frombuffer(raw, dtype=dtype, count=n)
        return {name: _squeeze(records[name]) for name, _, _ in header.fields}
    if header.data == "binary_compressed":
        return _compressed_columns(header, f, path)
    raise InvalidInput(
        f"{path}: unknown PCD DATA type {quote(header.data, 40)}; expected ascii, "
        "binary or binary_compressed. Re-save the file with PCL."
    )


def _check_room(n: int, record: int, f: BinaryIO, path: Path) -> None:
    """Refuse before reading when the rest of the file cannot hold ``n`` records.

    ``f.read(nbytes)`` allocates ``nbytes`` first, so an absurd point count in
    the header would fail as "out of memory" instead of "corrupt".
    """
    left = os.fstat(f.fileno()).st_size - f.tell()
    if n * record > left:
        raise InvalidInput(
            f"{path}: the header announces {n:,} points but the file holds only "
            f"about {max(left, 0) // max(record, 1):,}: the file is corrupt or "
            "truncated. Copy or export it again."
        )


def _compressed_columns(
    header: _Header, f: BinaryIO, path: Path
) -> dict[str, np.ndarray]:
    sizes = f.read(8)
    if len(sizes) < 8:  # PCL writes both sizes even for 0 points
        raise InvalidInput(
            f"{path} is truncated: its compressed data is missing. Copy or export "
            "it again."
        )
    packed_size, size = struct.unpack("<II", sizes)
    record = sum(np.dtype(code).itemsize * c for _, code, c in header.fields)
    # Both sizes come from the file: check them before allocating.
    left = os.fstat(f.fileno()).st_size - f.tell()
    if packed_size > left:
        raise InvalidInput(
            f"{path}: the compressed data announces {packed_size:,} bytes but the "
            f"file holds only {left:,} after the header: the file is corrupt or "
            "truncated. Copy or export it again."
        )
    if size != header.points * record:
        raise InvalidInput(
            f"{path}: the header announces {header.points:,} points "
            f"({header.points * record:,} bytes) but the compressed data says "
            f"{size:,} bytes: the file is corrupt or truncated. Copy or export "
            "it again."
        )
    if size > _LZF_MAX_RATIO * packed_size:
        raise InvalidInput(
            f"{path}: the header announces {header.points:,} points ({size:,} "
            f"bytes) but {packed_size:,} compressed bytes cannot hold that much "
            "(LZF expands at most 88 times): the file is corrupt or truncated. "
            "Copy or export it again."
        )
    try:
        raw = _lzf_decompress(f.read(packed_size), size)
    except (ValueError, IndexError) as exc:
        raise InvalidInput(
            f"{path}: its compressed point data are corrupt ({shorten(str(exc))}). "
            "Copy or export the file again."
        ) from exc
    out, pos, n = {}, 0, header.points
    for name, code, count in header.fields:  # column-major: one block per field
        nbytes = n * count * np.dtype(code).itemsize
        block = np.frombuffer(raw[pos : pos + nbytes], dtype="<" + code)
        _check_count(len(block) // count, n, path)
        out[name] = _squeeze(block.reshape(n, count))
        pos += nbytes
    return out


def _squeeze(arr: np.ndarray) -> np.ndarray:
    arr = arr.astype(arr.dtype.newbyteorder("="))
    return arr[:, 0] if arr.ndim == 2 and arr.shape[1] == 1 else arr


def _check_count(found: int, expected: int, path: Path) -> None:
    if found < expected:
        raise InvalidInput(
            f"{path} is truncated: it holds {found} of the {expected} points its "
            "header announces. Copy or export it again."
        )


def _unpack_rgb(columns: dict[str, np.ndarray]) -> None:
    for key in ("rgb", "rgba"):
        value = columns.get(key)
        if value is None or value.ndim != 1 or value.dtype.itemsize != 4:
            continue
        packed = (
            value.view(np.uint32)
            if value.dtype.kind == "f"
            else value.astype(np.uint32)
        )
        del columns[key]
        for name, shift in (("red", 16), ("green", 8), ("blue", 0)):
            columns[name] = ((packed >> shift) & 0xFF).astype(np.uint8)


def read_pcd(path: Path) -> RawCloud:
    """Read a PCD file; every field except x, y, z (and padding) is an attribute."""
    with open(path, "rb") as f:
        header = _parse_header(f, path)
        columns = _columns(header, f, path)
    lower = {name.lower(): name for name in columns}  # PDAL writes X Y Z
    if not {"x", "y", "z"} <= lower.keys():
        raise InvalidInput(
            f"{path}: the PCD file has no x, y and z fields (FIELDS "
            f"{shorten(' '.join(columns), 60)}). Re-save it with x y z fields."
        )
    coords = [columns.pop(lower[c]) for c in "xyz"]
    single = all(c.dtype == np.float32 for c in coords)
    xyz = np.column_stack(coords).astype(np.float32 if single else np.float64)
    attributes = {k: v for k, v in columns.items() if not k.startswith("_pad")}
    _unpack_rgb(attributes)
    meta = {"pcd_data": header.data, "coord_dtype": "float32" if single else "float64"}
    return RawCloud(xyz, np.zeros(3), attributes, meta)


def _fields(cloud: Cloud) -> dict[str, np.ndarray]:
    """Attributes to write: 1-D or (N, k) arrays; 8-bit RGB packed into 'rgb'."""
    out: dict[str, np.ndarray] = {}
    for name, value in cloud.attributes.items():
        value = np.asarray(value)
        width = int(np.prod(value.shape[1:]))
        arr = storable(value.reshape(len(cloud), width), allow_int64=True, name=name)
        if arr is not None:
            out[clean_name(name)] = arr[:, 0] if arr.shape[1] == 1 else arr
    rgb = [out.get(c) for c in ("red", "green", "blue")]
    if all(c is not None and c.ndim == 1 for c in rgb) and all(
        c.dtype.kind in "iu" and c.min(initial=0) >= 0 and c.max(initial=0) <= 255
        for c in cast("list[np.ndarray]", rgb)  # all set, checked just before
    ):
        r, g, b = (out.pop(c).astype(np.uint32) for c in ("red", "green", "blue"))
        out["rgb"] = ((r << 16) | (g << 8) | b).view(np.float32)  # PCL's convention
    return out


def write_pcd(path: Path, cloud: Cloud, *, binary: bool = True) -> None:
    """Write a PCD v0.7 file (binary or ascii) with x, y, z and every attribute."""
    fields = dict(
        zip("xyz", coordinate_columns(cloud, needs_double(cloud)), strict=True)
    )
    fields.update(_fields(cloud))
    n = len(cloud)
    blocks = {k: a.reshape(n, 1) if a.ndim == 1 else a for k, a in fields.items()}
    header = (
        "# .PCD v0.7 - Point Cloud Data file format\nVERSION 0.7\n"
        f"FIELDS {' '.join(blocks)}\n"
        f"SIZE {' '.join(str(a.dtype.itemsize) for a in blocks.values())}\n"
        f"TYPE {' '.join(a.dtype.kind.upper() for a in blocks.values())}\n"
        f"COUNT {' '.join(str(a.shape[1]) for a in blocks.values())}\n"
        f"WIDTH {n}\nHEIGHT 1\nVIEWPOINT 0 0 0 1 0 0 0\n"
        f"POINTS {n}\nDATA {'binary' if binary else 'ascii'}\n"
    )
    with open(path, "wb") as f:
        f.write(header.encode("ascii"))
        if binary:
            dtype = [(k, "<" + a.dtype.str[1:], a.shape[1:]) for k, a in blocks.items()]
            records = np.empty(n, dtype=dtype)
            for name, arr in blocks.items():
                records[name] = arr
            f.write(records.tobytes())
            return
        columns = [a[:, j] for a in blocks.values() for j in range(a.shape[1])]
        formats = [number_format(c.dtype, typed=True) for c in columns]
        for block in format_rows(columns, formats, " "):
            f.write(block.encode("ascii"))
