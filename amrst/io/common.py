"""Helpers shared by the format modules of :mod:`amrst.io` (private).

Readers return a :class:`RawCloud` (coordinates as stored, possibly with NaN rows);
:func:`amrst.io.read` validates it and chooses the offset. Writers receive a
:class:`~amrst.types.Cloud` and use the helpers here to pick coordinate precision,
flatten attributes and format text rows quickly.
"""

from __future__ import annotations

import logging
import re
from typing import TYPE_CHECKING, Any, NamedTuple

import numpy as np

if TYPE_CHECKING:
    from collections.abc import Iterator, Sequence
    from pathlib import Path

    from amrst.types import Cloud

logger = logging.getLogger(__name__)

#: Above this absolute coordinate (m) float32 no longer keeps millimetres.
LARGE_COORD_M = 1e4
#: Offsets chosen by readers are multiples of this (m).
OFFSET_STEP_M = 1000.0
_ROWS_PER_CHUNK = 100_000


class RawCloud(NamedTuple):
    """What a format reader found, before validation.

    ``xyz`` is (N, 3) float32 or float64 and may contain NaN/inf rows; world
    coordinates are ``xyz + offset``.
    """

    xyz: np.ndarray
    offset: np.ndarray
    attributes: dict[str, np.ndarray]
    meta: dict[str, Any]


def rebase(xyz: np.ndarray, offset: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Move large coordinates into the offset so local values stay small.

    Parameters
    ----------
    xyz : (N, 3) float
        Coordinates relative to ``offset``; NaN rows are ignored.
    offset : (3,) float64

    Returns
    -------
    xyz : (N, 3) float64
        Local coordinates.
    offset : (3,) float64
        The offset, shifted on each axis whose values exceed ``LARGE_COORD_M`` by
        the minimum rounded down to ``OFFSET_STEP_M``.
    """
    local = np.asarray(xyz, dtype=np.float64)
    offset = np.asarray(offset, dtype=np.float64).copy()
    finite = local[np.isfinite(local).all(axis=1)]
    if len(finite) == 0:
        return local, offset
    shift = np.floor(finite.min(axis=0) / OFFSET_STEP_M) * OFFSET_STEP_M
    shift[np.abs(finite).max(axis=0) <= LARGE_COORD_M] = 0.0
    if not shift.any():
        return local, offset
    return local - shift, offset + shift


def warn_undercount(path: Path, kind: str, announced: int, extra: int) -> None:
    """Log that a header announces fewer points than its file holds (not read)."""
    logger.warning(
        "%s: the %s header announces %d points but the file holds about %d more "
        "after them; only the announced %d were read. If points are missing, "
        "export the file again.",
        path.name,
        kind,
        announced,
        extra,
        announced,
    )


def count_data_lines(text: str, limit: int) -> int:
    """Count non-blank, non-comment lines of ``text``, stopping past ``limit``.

    Cheap when the text has no more newlines than ``limit`` (the common case).
    """
    if text.count("\n") < limit:
        return min(limit, text.count("\n") + 1)
    found = 0
    for line in text.split("\n"):
        stripped = line.strip()
        if stripped and not stripped.startswith("#"):
            found += 1
    return found


def shorten(text: str, limit: int = 80) -> str:
    """Return ``text`` cut to ``limit`` characters with an ellipsis, for messages.

    Bad input can hold whole lines of binary garbage; a message quotes at most
    ``limit`` characters of it.
    """
    return text if len(text) <= limit else text[: limit - 3] + "..."


def quote(text: str, limit: int = 80) -> str:
    """Return ``repr(text)`` (control bytes visible) cut to ``limit`` characters."""
    return shorten(repr(text), limit)


def needs_double(cloud: Cloud) -> bool:
    """Return True when float32 coordinates would lose precision for this cloud."""
    if np.any(cloud.offset != 0) or cloud.meta.get("coord_dtype") == "float64":
        return True
    return len(cloud) > 0 and float(np.abs(cloud.xyz).max()) > LARGE_COORD_M


def clean_name(name: str) -> str:
    """Make a field name usable in PLY/PCD headers and text headers (no spaces)."""
    return re.sub(r"[^A-Za-z0-9_]", "_", name.strip()) or "field"


def flat_attributes(cloud: Cloud) -> dict[str, np.ndarray]:
    """Attributes as 1-D arrays with clean names; (N, k) arrays become name_0.."""
    out: dict[str, np.ndarray] = {}
    for name, value in cloud.attributes.items():
        arr = np.asarray(value)
        key = clean_name(name)
        if key.lower() in ("x", "y", "z"):
            key = f"{key}_attr"
        if arr.ndim == 1:
            out[key] = arr
            continue
        arr = arr.reshape(len(arr), int(np.prod(arr.shape[1:])))
        for i in range(arr.shape[1]):
            out[f"{key}_{i}"] = arr[:, i]
    return out


def storable(
    arr: np.ndarray, *, allow_int64: bool, name: str = ""
) -> np.ndarray | None:
    """Cast an attribute to a dtype binary formats can store, without changing values.

    Bools become uint8 and float16 float32. 64-bit integers become 32-bit ones
    when the values fit and ``allow_int64`` is false, else float64. Returns None
    (and logs a warning) for non-numeric arrays.
    """
    kind = arr.dtype.kind
    if kind == "b":
        return arr.astype(np.uint8)
    if kind == "f":
        return arr.astype(np.float32) if arr.dtype.itemsize < 4 else arr
    if kind not in "iu":
        logger.warning(
            "Not writing attribute %r: dtype %s is not numeric.", name, arr.dtype
        )
        return None
    if arr.dtype.itemsize < 8 or allow_int64:
        return arr
    return narrow_int(arr) if len(arr) else arr.astype(np.int32)


def narrow_int(arr: np.ndarray) -> np.ndarray:
    """Cast ``arr`` to the smallest integer dtype holding it if all values are integers.

    Arrays with fractions, NaN or values beyond 32-bit range are returned as float64
    (exact for integers up to 2**53) or unchanged if already float.
    """
    if len(arr) == 0:
        return arr
    data = np.asarray(arr, dtype=np.float64)
    if not np.isfinite(data).all() or np.any(data != np.round(data)):
        return arr if arr.dtype.kind == "f" else data
    lo, hi = float(data.min()), float(data.max())
    for dtype in (np.uint8, np.int8, np.uint16, np.int16, np.uint32, np.int32):
        info = np.iinfo(dtype)
        if info.min <= lo and hi <= info.max:
            return data.astype(dtype)
    return data


def number_format(dtype: np.dtype, *, typed: bool = False) -> str:
    """Return a %-format that writes values of ``dtype`` as text without changing them.

    ``typed``: the file declares the dtype (PLY/PCD), so a float32 value only has
    to round-trip through float32; plain text is read back as float64.
    """
    if dtype.kind in "iub":
        return "%d"
    if typed and dtype.itemsize <= 4:
        return "%.9g"  # 9 significant digits round-trip any float32
    return "%r"  # Python's shortest repr round-trips any float64


def format_rows(
    columns: Sequence[np.ndarray], formats: Sequence[str], sep: str
) -> Iterator[str]:
    """Yield text blocks of ``sep``-separated rows, one %-operation per chunk.

    One format string over a whole chunk is faster than ``np.savetxt``, which
    formats row by row.
    """
    row = sep.join(formats) + "\n"
    n = len(columns[0]) if columns else 0
    for start in range(0, n, _ROWS_PER_CHUNK):
        stop = min(start + _ROWS_PER_CHUNK, n)
        block = np.empty((stop - start, len(columns)), dtype=object)
        for j, col in enumerate(columns):
            block[:, j] = col[start:stop].tolist()
        yield (row * (stop - start)) % tuple(block.ravel().tolist())


def coordinate_columns(cloud: Cloud, double: bool) -> list[np.ndarray]:
    """World x, y, z as three 1-D arrays (float64 if ``double`` else float32)."""
    world = cloud.xyz + cloud.offset
    dtype = np.float64 if double else np.float32
    return [world[:, i].astype(dtype) for i in range(3)]
