"""PLY point clouds, ASCII and binary (both endians), every vertex property kept.

Open3D keeps only positions, normals and colours, so this small reader/writer
uses numpy structured dtypes instead (private to amrst.io).
"""

from __future__ import annotations

import logging
from typing import TYPE_CHECKING, BinaryIO, NamedTuple

import numpy as np

from amrst.errors import InvalidInput
from amrst.io.common import (
    RawCloud,
    coordinate_columns,
    count_data_lines,
    flat_attributes,
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

logger = logging.getLogger(__name__)

_TYPES = {
    "char": "i1", "int8": "i1", "uchar": "u1", "uint8": "u1",
    "short": "i2", "int16": "i2", "ushort": "u2", "uint16": "u2",
    "int": "i4", "int32": "i4", "uint": "u4", "uint32": "u4",
    "float": "f4", "float32": "f4", "double": "f8", "float64": "f8",
}  # fmt: skip
_NAMES = {"i1": "char", "u1": "uchar", "i2": "short", "u2": "ushort",
          "i4": "int", "u4": "uint", "f4": "float", "f8": "double"}  # fmt: skip
_ENDIAN = {"binary_little_endian": "<", "binary_big_endian": ">", "ascii": "="}
_MAX_HEADER_LINES = 10_000


class _Element(NamedTuple):
    name: str
    count: int  # type: ignore[assignment]  # PLY's word; shadows tuple.count
    props: list[tuple[str, str]]  # (name, numpy code); code "list" for list props


class _Header(NamedTuple):
    fmt: str
    elements: list[_Element]
    comments: list[str]
    size: int  # bytes up to and including "end_header\n"


def _parse_header(f: BinaryIO, path: Path) -> _Header:
    if f.readline().strip() != b"ply":
        raise InvalidInput(
            f"{path} is not a PLY file (it does not start with 'ply'). Give it its "
            "real extension, or export the cloud again as PLY."
        )
    try:
        return _parse_header_lines(f, path)
    except (IndexError, ValueError) as exc:
        raise InvalidInput(
            f"{path}: malformed PLY header ({shorten(str(exc))}). The file is "
            "corrupt or truncated; export it again."
        ) from exc


def _parse_header_lines(f: BinaryIO, path: Path) -> _Header:
    fmt = ""
    elements: list[_Element] = []
    comments: list[str] = []
    for _ in range(_MAX_HEADER_LINES):
        line = f.readline()
        if not line:
            break
        words = line.decode("ascii", errors="replace").split()
        if not words or words[0] in ("obj_info",):
            continue
        if words[0] == "end_header":
            if fmt not in _ENDIAN:
                raise InvalidInput(
                    f"{path}: unknown PLY format {quote(fmt, 40)}; expected ascii, "
                    "binary_little_endian or binary_big_endian. Export it again."
                )
            return _Header(fmt, elements, comments, f.tell())
        if words[0] == "format":
            fmt = words[1]
        elif words[0] == "comment":
            comments.append(" ".join(words[1:]))
        elif words[0] == "element":
            if int(words[2]) < 0:
                raise ValueError(f"element {quote(words[1], 40)} has a negative count")
            elements.append(_Element(words[1], int(words[2]), []))
        elif words[0] == "property" and elements:
            code = "list" if words[1] == "list" else _TYPES.get(words[1])
            if code is None:
                raise InvalidInput(
                    f"{path}: unknown PLY property type {quote(words[1], 40)}; the "
                    "header is corrupt or truncated. Export the file again."
                )
            elements[-1].props.append((words[-1], code))
    raise InvalidInput(
        f"{path}: the PLY header never ends (no 'end_header' line); the file is "
        "corrupt or truncated. Export it again."
    )


def _vertex(header: _Header, path: Path) -> tuple[_Element, list[_Element]]:
    """Return the vertex element and the elements stored before it."""
    for i, element in enumerate(header.elements):
        if element.name == "vertex":
            if any(code == "list" for _, code in element.props):
                raise InvalidInput(
                    f"{path}: list properties on vertices are not supported. "
                    "Re-save the PLY with scalar vertex properties only."
                )
            return element, header.elements[:i]
    raise InvalidInput(
        f"{path}: the PLY file has no 'vertex' element (no points; perhaps a "
        "mesh without vertices). Export the point cloud again as PLY."
    )


def _read_binary(f: BinaryIO, header: _Header, path: Path) -> np.ndarray:
    vertex, before = _vertex(header, path)
    endian = _ENDIAN[header.fmt]
    skip = 0
    for element in before:
        if any(code == "list" for _, code in element.props):
            raise InvalidInput(
                f"{path}: element {quote(element.name, 40)} with list properties "
                "comes before the vertices. Re-save the PLY with the vertices first."
            )
        skip += (
            element.count
            * np.dtype([(n, endian + c) for n, c in element.props]).itemsize
        )
    dtype = np.dtype([(n, endian + c) for n, c in vertex.props])
    record = max(dtype.itemsize, 1)
    # Check the size before reading: read() allocates what the header announces.
    left = path.stat().st_size - header.size - skip
    if vertex.count * dtype.itemsize > left:
        raise InvalidInput(
            f"{path}: the header announces {vertex.count:,} points but the file "
            f"holds only about {max(left, 0) // record:,}: the file is corrupt or "
            "truncated. Copy or export it again."
        )
    if vertex is header.elements[-1] and left - vertex.count * dtype.itemsize >= record:
        extra = (left - vertex.count * dtype.itemsize) // record
        logger.warning(
            "%s: the PLY header announces %d points but the file holds about %d "
            "more after them; only the announced %d were read. If points are "
            "missing, export the file again.",
            path.name,
            vertex.count,
            extra,
            vertex.count,
        )
    f.seek(skip, 1)
    return np.frombuffer(f.read(vertex.count * dtype.itemsize), dtype=dtype)


def _read_ascii(f: BinaryIO, header: _Header, path: Path) -> np.ndarray:
    """Read the vertices of an ASCII PLY, a line at a time; the text whole on an error.

    ``f`` stands just after the header.
    """
    vertex, before = _vertex(header, path)
    skip = sum(element.count for element in before)
    last = vertex is header.elements[-1]  # else the lines after it are other elements
    data, extra = stream_rows(f, vertex.count, len(vertex.props), skip=skip, after=last)
    if data is None or len(data) < vertex.count:
        f.seek(header.size)
        return _read_ascii_whole(f, header, path)
    if extra:
        warn_undercount(path, "PLY", vertex.count, extra)
    return _vertices(data, vertex)


def _read_ascii_whole(f: BinaryIO, header: _Header, path: Path) -> np.ndarray:
    """Read the vertices from the whole text: errors name the line at fault."""
    vertex, before = _vertex(header, path)
    lines = f.read().decode("ascii", errors="replace").split("\n")
    skip = sum(element.count for element in before)
    body = "\n".join(lines[skip:])
    f.seek(0)
    first_line_no = f.read(header.size).count(b"\n") + skip + 1
    data = parse_numbers(
        body, len(vertex.props), None, first_line_no, path, max_rows=vertex.count
    )
    if len(data) < vertex.count:
        raise InvalidInput(
            f"{path} is truncated: it holds {len(data)} of the {vertex.count} points "
            "its header announces. Copy or export it again."
        )
    if vertex is header.elements[-1]:
        found = count_data_lines(body, vertex.count)
        if found > vertex.count:
            warn_undercount(path, "PLY", vertex.count, found - vertex.count)
    return _vertices(data, vertex)


def _vertices(data: np.ndarray, vertex: _Element) -> np.ndarray:
    out = np.empty(len(data), dtype=[(n, c) for n, c in vertex.props])
    for i, (name, _) in enumerate(vertex.props):
        out[name] = data[:, i]
    return out


def read_ply(path: Path) -> RawCloud:
    """Read PLY vertices; every property except x, y, z becomes an attribute."""
    with open(path, "rb") as f:
        header = _parse_header(f, path)
        reader = _read_ascii if header.fmt == "ascii" else _read_binary
        vertices = reader(f, header, path)
    lower = {name.lower(): name for name in vertices.dtype.names or ()}
    if not {"x", "y", "z"} <= lower.keys():
        raise InvalidInput(
            f"{path}: the vertices have no x, y and z properties. Export the cloud "
            "again with its x, y and z coordinates."
        )
    coords = [vertices[lower[c]] for c in "xyz"]
    single = all(c.dtype.kind == "f" and c.dtype.itemsize == 4 for c in coords)
    xyz = np.column_stack(coords).astype(np.float32 if single else np.float64)
    attributes = {
        name: vertices[name].astype(vertices.dtype[name].newbyteorder("="))
        for name in vertices.dtype.names or ()
        if name.lower() not in ("x", "y", "z")
    }
    meta = {
        "ply_format": header.fmt,
        "coord_dtype": "float32" if single else "float64",
        "ply_comments": tuple(header.comments),
    }
    return RawCloud(xyz, np.zeros(3), attributes, meta)


def write_ply(path: Path, cloud: Cloud, *, binary: bool = True) -> None:
    """Write a PLY (binary little endian or ASCII) with x, y, z and every attribute.

    Coordinates are doubles when float32 would lose millimetres (large values or a
    nonzero offset), floats otherwise.
    """
    columns = dict(
        zip("xyz", coordinate_columns(cloud, needs_double(cloud)), strict=True)
    )
    for name, arr in flat_attributes(cloud).items():
        value = storable(arr, allow_int64=False, name=name)
        if value is not None:
            columns[name] = value
    fmt = "binary_little_endian" if binary else "ascii"
    props = "".join(
        f"property {_NAMES[a.dtype.str[1:]]} {name}\n" for name, a in columns.items()
    )
    header = (
        f"ply\nformat {fmt} 1.0\ncomment written by AMRST Studio\n"
        f"element vertex {len(cloud)}\n{props}end_header\n"
    )
    with open(path, "wb") as f:
        f.write(header.encode("ascii"))
        if binary:
            dtype = np.dtype([(n, "<" + a.dtype.str[1:]) for n, a in columns.items()])
            records = np.empty(len(cloud), dtype=dtype)
            for name, arr in columns.items():
                records[name] = arr
            f.write(records.tobytes())
            return
        formats = [number_format(a.dtype, typed=True) for a in columns.values()]
        for block in format_rows(list(columns.values()), formats, " "):
            f.write(block.encode("ascii"))
