"""Delimited text point clouds: .xyz .txt .asc .csv .pts (private to amrst.io).

One point per line; space, tab, comma or semicolon separated (semicolon files may
use decimal commas). An optional header line names the columns (``x y z``,
``"X" "Y" "Z"``, ``//X,Y,Z,R,G,B``); a first line holding only the point count
(the .pts convention) is skipped.
"""

from __future__ import annotations

import io
import itertools
import logging
import warnings
from typing import TYPE_CHECKING, BinaryIO

import numpy as np

from amrst.errors import InvalidInput
from amrst.io.common import (
    RawCloud,
    coordinate_columns,
    flat_attributes,
    format_rows,
    narrow_int,
    number_format,
    quote,
    shorten,
    storable,
)

if TYPE_CHECKING:
    from collections.abc import Iterable, Sequence
    from pathlib import Path

    from amrst.types import Cloud

logger = logging.getLogger(__name__)

_ALIASES = {"r": "red", "g": "green", "b": "blue", "i": "intensity"}
_COORD_FORMAT = "%.6f"  # micrometres; float64 world values keep them up to 1e9 m
_SNIFF_CHARS = 4096  # the start of the file looked at to tell text from binary
_HEAD_BYTES = 1_000_000  # the start of the file its layout is read from ...
_MAX_HEAD_BYTES = 64_000_000  # ... read further past comments up to this
_MAX_CONTROL_SHARE = 0.05  # more control characters than this: binary
_MAX_UNDECODABLE_SHARE = 0.3  # more bytes that are not UTF-8 than this: binary
_TEXT_CONTROLS = frozenset("\t\n\r\f\v\x1a")  # \x1a: DOS end-of-file mark
#: More values on a line than this is no point a line (lost line breaks): refused
#: before numpy parses a line of millions of columns.
MAX_COLUMNS = 256


class _Layout:
    """Where the numbers start and how they are separated."""

    def __init__(self, text: str, path: Path) -> None:
        self.header: list[str] | None = None
        self.count: int | None = None  # the .pts point-count line's
        lines = _leading_lines(text, 3)
        if not lines:
            raise InvalidInput(
                f"{path} has no data lines (only blanks or # comments). "
                "Export the point cloud again with one 'x y z' point per line."
            )
        first = lines[0][1]
        tokens = _split(first, _delimiter(first))
        skip = 0
        if len(tokens) == 1 and _is_int(tokens[0]) and len(lines) == 1:
            raise InvalidInput(
                f"{path} has no points: it holds only the point-count line "
                f"({quote(tokens[0], 20)}). Check that the export finished and "
                "wrote the points."
            )
        if len(tokens) == 1 and _is_int(tokens[0]):
            skip = 1  # .pts: the first line is the point count
            self.count = int(tokens[0])
        elif not all(_is_number(t) for t in tokens):
            self.header, skip = [_clean(t) for t in tokens], 1
        if skip >= len(lines):
            raise InvalidInput(
                f"{path} has a header line but no points. "
                "Check that the export finished and wrote the points."
            )
        self.first_line_no, data = lines[skip]
        self.delimiter = _delimiter(data)
        self.n_columns = len(_split(data, self.delimiter))


def _leading_lines(text: str, n: int) -> list[tuple[int, str]]:
    """List the first ``n`` non-blank, non-comment lines with their 1-based numbers."""
    found: list[tuple[int, str]] = []
    for no, line in enumerate(text.split("\n"), start=1):
        if line.strip() and not line.lstrip().startswith("#"):
            found.append((no, line))
            if len(found) == n:
                break
    return found


def _line_start(text: str, line_no: int) -> int:
    pos = 0
    for _ in range(line_no - 1):
        pos = text.index("\n", pos) + 1
    return pos


def _delimiter(line: str) -> str | None:
    """';' (decimal commas allowed), ',' or None for any whitespace."""
    if ";" in line:
        return ";"
    return "," if "," in line else None


def _split(line: str, delimiter: str | None) -> list[str]:
    if delimiter == ";":
        line = line.replace(",", ".")
    return [t.strip() for t in line.strip().split(delimiter)]


def _clean(token: str) -> str:
    name = token.strip().lstrip("/").strip().strip("\"'").strip().lower()
    return _ALIASES.get(name, name.replace(" ", "_"))


def _is_number(token: str) -> bool:
    try:
        float(token)
    except ValueError:
        return False
    return True


def _is_int(token: str) -> bool:
    return token.isdigit()


def _column_names(
    layout: _Layout, columns: Sequence[str] | None, path: Path
) -> tuple[list[str], str]:
    """Name every column; also return a warning to log once the numbers parsed.

    Names: the caller's, the header's, or x y z intensity col4..; warning: "" if
    none.
    """
    n = layout.n_columns
    if columns is not None:
        names = [str(c).strip().lower() for c in columns]
        if len(names) > n:
            raise InvalidInput(
                f"columns= names {len(names)} columns but {path} has {n} per line. "
                "Give at most one name per column."
            )
    elif layout.header is not None:
        names = layout.header[:n]
    else:
        names = ["x", "y", "z", "intensity"][:n]
    names += [f"col{i}" for i in range(len(names), n)]
    names = [name or f"col{i}" for i, name in enumerate(names)]
    if not {"x", "y", "z"} <= set(names):
        if columns is not None:
            raise InvalidInput(
                f"columns= must include 'x', 'y' and 'z'; got {list(columns)}. Name "
                "the coordinate columns x, y and z."
            )
        warning = (
            f"{path.name}: header {shorten(str(names))} has no x/y/z columns; "
            "using the first three as x, y, z."
        )
        return _unique(["x", "y", "z", *names[3:]]), warning
    return _unique(names), ""


def _unique(names: list[str]) -> list[str]:
    seen: dict[str, int] = {}
    out = []
    for name in names:
        seen[name] = seen.get(name, 0) + 1
        out.append(name if seen[name] == 1 else f"{name}_{seen[name] - 1}")
    return out


def parse_numbers(
    text: str,
    n_columns: int,
    delimiter: str | None,
    first_line_no: int,
    path: Path,
    max_rows: int | None = None,
) -> np.ndarray:
    """(rows, n_columns) float64 from numeric text; errors name the bad line.

    ``np.loadtxt`` (C parser since numpy 1.23) reads 1M rows x 4 columns in under
    a second. On failure the text is scanned line by line to report the line.
    ``max_rows`` (a header's count, which may be absurd) never exceeds the number
    of lines.
    """
    if delimiter == ";":
        text = text.replace(",", ".")
    if max_rows is not None:  # loadtxt allocates max_rows rows up front
        max_rows = min(max_rows, text.count("\n") + 1)
    try:
        data = _loadtxt(io.StringIO(text, newline=None), delimiter, max_rows)
    except ValueError as exc:
        raise _locate_error(
            text, n_columns, delimiter, first_line_no, path, exc
        ) from exc
    if data.size == 0:
        return np.empty((0, n_columns))
    if data.shape[1] != n_columns:
        raise _locate_error(text, n_columns, delimiter, first_line_no, path, None)
    return data


def stream_numbers(
    lines: Iterable[str], n_columns: int, delimiter: str | None
) -> np.ndarray | None:
    """Parse numeric lines read a line at a time (an open file) with numpy's C reader.

    Memory holds the numbers, not the text. None when the lines are not ``n_columns``
    numbers each: the caller then parses the text whole with :func:`parse_numbers`,
    which names the line at fault.
    """
    try:
        data = _loadtxt(lines, delimiter, None)
    except ValueError:
        return None
    if data.size == 0:
        return np.empty((0, n_columns))
    return data if data.shape[1] == n_columns else None


def stream_rows(
    f: BinaryIO, n: int, n_columns: int, *, skip: int = 0, after: bool = True
) -> tuple[np.ndarray | None, int]:
    """Parse ``n`` rows of numbers from the ASCII lines of a binary file, one at a time.

    The body of an ASCII PLY or PCD: ``skip`` lines first (another element's), then
    exactly ``n`` lines, so a blank or missing one shows as a row too few. Returns
    the rows (None, or fewer than ``n``, when the lines are not that: the caller then
    parses the text whole, which names the line at fault) and, with ``after``, how
    many data lines follow them (a header that undercounts its points). ``f`` is
    left where the lines read end.
    """
    lines = io.TextIOWrapper(f, encoding="ascii", errors="replace")
    for _ in range(skip):
        lines.readline()
    rows = stream_numbers(itertools.islice(lines, n), n_columns, None)
    extra = 0
    if after and rows is not None and len(rows) == n:
        extra = sum(1 for ln in lines if ln.strip() and not ln.lstrip().startswith("#"))
    lines.detach()
    return rows, extra


def _loadtxt(
    source: Iterable[str], delimiter: str | None, max_rows: int | None
) -> np.ndarray:
    """Parse lines of numbers (a file, or any iterable of lines) with numpy's C reader."""
    with warnings.catch_warnings():
        # An empty body is reported by the caller as "no points", not a warning.
        warnings.filterwarnings("ignore", message=".*input contained no data")
        return np.loadtxt(
            source,
            delimiter=delimiter,
            ndmin=2,
            comments="#",
            dtype=np.float64,
            max_rows=max_rows,
        )


def _locate_error(
    text: str,
    n_columns: int,
    delimiter: str | None,
    first_line_no: int,
    path: Path,
    exc: ValueError | None,
) -> InvalidInput:
    for no, line in enumerate(text.split("\n"), start=first_line_no):
        if not line.strip() or line.lstrip().startswith("#"):
            continue
        tokens = line.split("#")[0].strip().split(delimiter)
        if len(tokens) != n_columns:
            return InvalidInput(
                f"{path}, line {no}: {len(tokens)} values where {n_columns} were "
                f"expected ({quote(line.strip(), 60)}). Fix or delete that line."
            )
        bad = [t for t in tokens if not _is_number(t)]
        if bad:
            return InvalidInput(
                f"{path}, line {no}: {quote(bad[0].strip(), 40)} is not a number. "
                "Fix or delete that line (or remove the extra header lines)."
            )
    return InvalidInput(
        f"{path}: could not parse the numbers ({shorten(str(exc))}). Check that "
        "it holds one point per line."
    )


def _check_is_text(text: str, path: Path) -> None:
    """Refuse a PLY, PCD, LAS or binary file given a text extension.

    Parsing it as text would quote lines of binary garbage, or complain that
    the word 'format' of a PLY header is not a number.
    """
    head = text[:_SNIFF_CHARS]
    first = head.split("\n", 1)[0].strip()
    kind = (
        "PLY" if first == "ply"
        else "PCD" if first.startswith(("# .PCD", "VERSION"))
        else "LAS/LAZ" if head.startswith("LASF")
        else None
    )  # fmt: skip
    if kind is None:
        controls = sum(1 for c in head if _is_control(c))
        undecodable = head.count("\ufffd")  # a few are accents in another encoding
        if (
            "\x00" in head
            or controls > _MAX_CONTROL_SHARE * len(head)
            or undecodable > _MAX_UNDECODABLE_SHARE * len(head)
        ):
            kind = "binary"
    if kind is None:
        return
    extension = {
        "PLY": ".ply",
        "PCD": ".pcd",
        "LAS/LAZ": ".las or .laz",
        "binary": "such as .las, .laz, .ply or .pcd",
    }[kind]
    raise InvalidInput(
        f"{path} is not a text point cloud (it looks like a {kind} file): give it "
        f"its real extension ({extension}), or export the cloud again as text."
    )


def _is_control(char: str) -> bool:
    return (char < " " or char == "\x7f") and char not in _TEXT_CONTROLS


def read_text(path: Path, columns: Sequence[str] | None = None) -> RawCloud:
    """Read a delimited text point cloud; see the module docstring for the layout."""
    head, encoding = _head(path)
    _check_is_text(head, path)
    layout = _Layout(head, path)
    if layout.n_columns < 3:
        raise InvalidInput(
            f"{path} has {layout.n_columns} value(s) per line; at least x, y, z "
            "are needed. Check the separator and the export settings."
        )
    if layout.n_columns > MAX_COLUMNS:
        raise InvalidInput(
            f"{path} has {layout.n_columns:,} values on a line; a point cloud holds "
            "one point a line (x, y, z and its attributes). Check the line breaks "
            "and the export settings."
        )
    names, warning = _column_names(layout, columns, path)
    data = _parse_body(path, encoding, layout)
    if layout.count is not None and len(data) < layout.count:
        # More points than the count is a file of several scans or a miscount; fewer
        # is an export or a copy that stopped.
        raise InvalidInput(
            f"{path} holds {len(data):,} points but its first line says "
            f"{layout.count:,}: the file is cut short. Export or copy it again."
        )
    if warning:  # after the parse: a refusal stays one line
        logger.warning("%s", warning)
    index = {name: i for i, name in enumerate(names)}
    xyz = data[:, [index["x"], index["y"], index["z"]]]
    attributes = {
        name: narrow_int(data[:, i])
        for i, name in enumerate(names)
        if name not in ("x", "y", "z")
    }
    meta = {
        "text_delimiter": layout.delimiter or " ",
        "text_header": layout.header is not None,
        "text_columns": tuple(names),
    }
    return RawCloud(xyz, np.zeros(3), attributes, meta)


def _head(path: Path) -> tuple[str, str]:
    r"""Return the file's first lines as text, and its encoding.

    At least ``_HEAD_BYTES`` are read, and more (doubling, up to ``_MAX_HEAD_BYTES``)
    until the text holds the three data lines the layout is read from, so a long
    comment block is no obstacle. Line ends are made ``\n`` (``\r\n`` and the old
    ``\r`` as well), as the body is read. Windows tools often save UTF-16 (with a
    byte-order mark); everything else is read as UTF-8, whose first 128 characters
    are the ASCII of the numbers.
    """
    size = _HEAD_BYTES
    with path.open("rb") as fh:
        raw = fh.read(size)
        encoding = "utf-16" if raw[:2] in (b"\xff\xfe", b"\xfe\xff") else "utf-8-sig"
        while True:
            more = bool(fh.read(1))
            text = _newlines(raw.decode(encoding, errors="replace"))
            if more:  # the last line may be cut short
                text = text[: text.rfind("\n") + 1]
            enough = len(_leading_lines(text, 3)) == 3
            if not more or enough or len(raw) >= _MAX_HEAD_BYTES:
                return text, encoding
            fh.seek(len(raw))
            raw += fh.read(size)
            size *= 2


def _newlines(text: str) -> str:
    r"""Return ``text`` with ``\r\n`` and ``\r`` line ends made ``\n``."""
    return text.replace("\r\n", "\n").replace("\r", "\n")


def _parse_body(path: Path, encoding: str, layout: _Layout) -> np.ndarray:
    """Parse the numbers from the first data line on, reading the file a line at a time.

    Memory holds the numbers, not the file's text. On a parse error the file is read
    again whole, to name the line at fault.
    """
    with path.open(encoding=encoding, errors="replace") as fh:
        for _ in range(layout.first_line_no - 1):
            fh.readline()
        lines: Iterable[str] = fh
        if layout.delimiter == ";":  # decimal commas
            lines = (line.replace(",", ".") for line in fh)
        data = stream_numbers(lines, layout.n_columns, layout.delimiter)
    if data is None:
        text = _newlines(path.read_bytes().decode(encoding, errors="replace"))
        return parse_numbers(
            text[_line_start(text, layout.first_line_no) :],
            layout.n_columns,
            layout.delimiter,
            layout.first_line_no,
            path,
        )
    return data


def write_text(
    path: Path, cloud: Cloud, *, binary: bool = True, sep: str = " "
) -> None:
    """Write world x y z plus every attribute as columns, after a header line.

    ``binary`` is ignored (text is text); it keeps the writer signature uniform.
    """
    attrs = {}
    for name, values in flat_attributes(cloud).items():
        value = storable(values, allow_int64=True, name=name)
        if value is not None:
            attrs[name] = value
    names = ["x", "y", "z", *attrs]
    columns = [*coordinate_columns(cloud, double=True), *attrs.values()]
    formats = [_COORD_FORMAT] * 3 + [number_format(a.dtype) for a in attrs.values()]
    with open(path, "w", encoding="utf-8", newline="\n") as f:
        f.write(sep.join(names) + "\n")
        for block in format_rows(columns, formats, sep):
            f.write(block)
