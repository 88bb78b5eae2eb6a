"""Decoding LAS/LAZ points through laspy, whatever LASzip variant wrote them.

Private to :mod:`amrst.io`. lazrs (laspy's default LAZ backend) cannot read the
pointwise, chunk-table-less files of early LASzip versions (it panics: "Variable-size
chunks, but no chunk table"), so those go to laspy's ``laszip`` backend; without it
they are refused with one line naming the compressor version. Decoder noise (laspy's
``ERROR: ...`` log lines, a Rust panic message on stderr) never reaches the user: the
outcome is one :class:`~amrst.errors.InvalidInput` or a logged warning.
"""

from __future__ import annotations

import contextlib
import logging
import os
import struct
import sys
import threading
from typing import TYPE_CHECKING, Any, NamedTuple

from amrst.errors import InvalidInput

if TYPE_CHECKING:
    from collections.abc import Iterator
    from pathlib import Path

logger = logging.getLogger(__name__)

_VLR_HEADER = 54
_VARIABLE_CHUNKS = 0xFFFFFFFF
_MAX_CHUNK_BYTES = (
    256 * 2**20
)  # a chunk larger than the file's points is corrupt past this
_COMPRESSORS = {0: "none", 1: "pointwise", 2: "pointwise-chunked", 3: "layered-chunked"}
_quiet_lock = threading.Lock()
_quiet_depth = 0
_saved_fd: int | None = None


class LazInfo(NamedTuple):
    """What the LASzip VLR and the chunk table say (None: not found)."""

    compressor: int
    version: str  # e.g. "1.2r0"
    chunk_size: int  # _VARIABLE_CHUNKS for variable-size chunks
    n_chunks: int | None  # from the chunk table; None when there is none
    coder: int = 0  # 0: arithmetic, the only one LASzip defines
    items: tuple[tuple[int, int, int], ...] = ()  # (type, size, version) per item
    point_start: int = 0  # where the points (the chunk table's offset) begin
    table_start: int = -1  # where the chunk table begins
    record: bytes = b""  # the VLR's record data, as lazrs takes it

    def describe(self) -> str:
        """Name the LASzip version and compressor, for messages."""
        kind = _COMPRESSORS.get(self.compressor, f"compressor {self.compressor}")
        return f"LASzip {self.version} ({kind})"

    @property
    def needs_laszip(self) -> bool:
        """Tell whether lazrs cannot read it (it needs chunks and a chunk table)."""
        return self.compressor < 2 or self.n_chunks is None


def laz_info(path: Path, head: bytes) -> LazInfo | None:
    """Read the LASzip VLR and the chunk table's size; None when there is no VLR."""
    header_size, point_start, n_vlrs = struct.unpack_from("<HII", head, 94)
    size = path.stat().st_size
    with open(path, "rb") as f:
        pos = header_size
        for _ in range(n_vlrs):
            f.seek(pos)
            vlr = f.read(_VLR_HEADER)
            if len(vlr) < _VLR_HEADER or pos + _VLR_HEADER > point_start:
                return None
            record_id, length = struct.unpack_from("<HH", vlr, 18)
            if vlr[2:18].rstrip(b"\0") == b"laszip encoded" and record_id == 22204:
                data = f.read(length)
                if len(data) < 16:
                    return None
                compressor, coder, major, minor, rev, _, chunk = struct.unpack_from(
                    "<HHBBHII", data
                )
                items = _items(data)
                break
            pos += _VLR_HEADER + length
        else:
            return None
        f.seek(point_start)
        raw = f.read(8)
        (table_start,) = struct.unpack("<q", raw) if len(raw) == 8 else (-1,)
        if table_start == -1 and size >= point_start + 16:  # written at the end
            f.seek(size - 8)
            (table_start,) = struct.unpack("<q", f.read(8))
        n_chunks = None
        if compressor >= 2 and point_start < table_start <= size - 8:
            f.seek(table_start)
            version, count = struct.unpack("<II", f.read(8))
            if version == 0 and count > table_start - point_start:
                # Each chunk takes at least a byte: lazrs would allocate the table
                # for this count and abort the process.
                raise InvalidInput(
                    f"{path}: corrupt LAZ chunk table: it lists {count:,} chunks in "
                    f"{table_start - point_start:,} bytes of points. The file is "
                    "corrupt or truncated; copy or export it again."
                )
            if version == 0:
                n_chunks = count
    version = f"{major}.{minor}r{rev}"
    return LazInfo(
        compressor,
        version,
        chunk,
        n_chunks,
        coder,
        items,
        point_start,
        table_start,
        data,
    )


def _items(data: bytes) -> tuple[tuple[int, int, int], ...]:
    """Return the VLR's items as (type, size, version); () when cut short."""
    if len(data) < 34:
        return ()
    (n_items,) = struct.unpack_from("<H", data, 32)
    if len(data) < 34 + 6 * n_items:
        return ()
    return tuple(struct.unpack_from("<HHH", data, 34 + 6 * k) for k in range(n_items))


# LASzip item type: (its size in bytes or None when any, the versions decoders know)
_ITEMS = {
    0: (None, (1, 2)),  # extra bytes (LAS 1.0-1.3 point formats)
    6: (20, (1, 2)),  # point 1.0
    7: (8, (1, 2)),  # GPS time
    8: (6, (1, 2)),  # RGB
    9: (29, (1, 2)),  # wave packet (lazrs writes version 2)
    10: (30, (3, 4)),  # point 1.4
    11: (6, (3, 4)),  # RGB 1.4
    12: (8, (3, 4)),  # RGB + NIR 1.4
    13: (29, (3, 4)),  # wave packet 1.4
    14: (None, (3, 4)),  # extra bytes 1.4
}


def check_laz_vlr(path: Path, info: LazInfo, record_length: int, n_points: int) -> None:
    """Refuse a LASzip VLR no decoder can follow, before any point is decoded.

    A damaged VLR (a chunk size far beyond the points, an unknown coder, item or
    item version, or item sizes that do not add up to the point record) sends
    lazrs's parallel decoder after absurd allocations (chunk size x record
    length), which abort the whole process instead of raising.
    """
    problem = None
    chunk_bytes = info.chunk_size * max(record_length, 1)
    if (
        info.chunk_size != _VARIABLE_CHUNKS
        and info.chunk_size > n_points
        and chunk_bytes > _MAX_CHUNK_BYTES
    ):
        problem = (
            f"its chunk size is {info.chunk_size:,} points ({chunk_bytes / 1e9:.1f} GB "
            f"to decode one chunk) for a file of {n_points:,} points"
        )
    elif info.coder != 0:
        problem = f"its coder is {info.coder} (LASzip defines only 0)"
    elif info.compressor > 3:
        problem = f"its compressor is {info.compressor} (LASzip defines 0 to 3)"
    elif info.items:
        for kind, size, version in info.items:
            known = _ITEMS.get(kind)
            if known is None:
                problem = f"it lists an unknown item type {kind}"
            elif known[0] is not None and size != known[0]:
                problem = f"item type {kind} has size {size}, not {known[0]}"
            elif version not in known[1]:
                problem = f"item type {kind} has an unknown version {version}"
            if problem:
                break
        total = sum(size for _, size, _ in info.items)
        if problem is None and total != record_length:
            problem = (
                f"its items add up to {total} bytes a point but the header's point "
                f"records are {record_length} bytes"
            )
    else:
        problem = "its item list is missing or cut short"
    if problem:
        raise InvalidInput(
            f"{path}: corrupt LAZ compression record (LASzip VLR): {problem}. "
            "The file is corrupt; copy or export it again."
        )


def check_laz_count(
    path: Path, n_points: int, info: LazInfo, record_length: int
) -> None:
    """Refuse a LAZ whose header announces more points than its chunks can hold.

    LASzip stores points in chunks of a fixed size and lists the chunks in a table
    at the end. The decoder allocates the announced count first: 2**28 announced
    points take 5 GB and many seconds before failing. A header announcing fewer
    points than the chunks hold is reported (the rest are not read): fewer than
    all but the last chunk hold, from the table alone, and fewer than the last
    chunk holds by :func:`_check_last_chunk`.
    """
    if info.n_chunks is None or info.chunk_size == 0:
        return
    if info.chunk_size == _VARIABLE_CHUNKS:
        _check_last_chunk(path, n_points, info, record_length)
        return
    capacity = info.n_chunks * info.chunk_size
    if n_points > capacity:
        raise InvalidInput(
            f"{path}: corrupt LAZ header: it announces {n_points:,} points but the "
            f"file's {info.n_chunks:,} compressed chunks hold at most {capacity:,}. "
            "The file is corrupt or truncated; copy or export it again."
        )
    # The last chunk may hold no point (lazrs writes one empty chunk for 0 points).
    at_least = (info.n_chunks - 1) * info.chunk_size
    if n_points >= at_least:
        _check_last_chunk(path, n_points, info, record_length)
        return
    _warn_more(
        path,
        n_points,
        f"its {info.n_chunks} compressed chunks hold at least {at_least}",
    )


#: An honest chunk compresses back to its own size (LASzip's coder is
#: deterministic); a last chunk larger than this many times what its announced
#: points take, plus _SPARE_BYTES, holds points the header does not count. The
#: margin leaves room for writers whose coder differs in details.
_CHUNK_SLACK = 1.5
_SPARE_BYTES = 64


def _check_last_chunk(
    path: Path, n_points: int, info: LazInfo, record_length: int
) -> None:
    """Warn when the last chunk holds more points than the header announces.

    A chunk has no end a decoder stops at: the header's count decides how many
    points are read. Variable-size chunks list their point counts in the chunk
    table, which are added up; a fixed-size chunk's announced points are decoded
    and compressed again, and compared with the chunk's size in the table. A file
    lazrs cannot decode is left to the full decode, which reports it.
    """
    if info.needs_laszip or info.n_chunks is None or info.n_chunks > n_points + 1:
        return  # a table longer than the points: nothing to compare with
    with quiet_decoders():
        try:
            found = _last_chunk(path, n_points, info, record_length)
        except BaseException as exc:
            if not (isinstance(exc, Exception) or is_panic(exc)):
                raise
            return
    if found is None:
        return  # a damaged table: the full decode reports what it can
    table, needed = found
    if info.chunk_size == _VARIABLE_CHUNKS:
        held = sum(count for count, _ in table)
        if n_points < held:
            _warn_more(path, n_points, f"its chunk table counts {held:,}")
    elif table and table[-1][1] > _CHUNK_SLACK * needed + _SPARE_BYTES:
        _warn_more(
            path,
            n_points,
            f"its last compressed chunk takes {table[-1][1]:,} bytes, more than "
            f"the {needed:,} its announced points take (it holds more points)",
        )


def _last_chunk(
    path: Path, n_points: int, info: LazInfo, record_length: int
) -> tuple[list[tuple[int, int]], int] | None:
    """Read the chunk table and compress the last chunk's announced points again.

    Returns
    -------
    table : list of (points, bytes)
        One entry a chunk.
    needed : int
        The bytes the last chunk's announced points take compressed (0 for
        variable-size chunks, whose table counts their points).
    None
        The table's chunks do not fill the space between the points' start and
        the table: it is damaged.
    """
    import lazrs

    vlr = lazrs.LazVlr(info.record)
    with open(path, "rb") as f:
        f.seek(info.point_start)
        table = [(int(c), int(b)) for c, b in lazrs.read_chunk_table(f, vlr)]
        if sum(b for _, b in table) != info.table_start - info.point_start - 8:
            return None
        if info.chunk_size == _VARIABLE_CHUNKS or not table:
            return table, 0
        first = (len(table) - 1) * info.chunk_size
        points = bytearray((n_points - first) * record_length)
        if points:
            f.seek(info.point_start)
            decoder = lazrs.LasZipDecompressor(f, info.record)
            decoder.seek(first)
            decoder.decompress_many(points)
    packed = bytes(lazrs.compress_points(vlr, bytes(points), False))
    # lazrs writes the chunk table's offset, the chunk, then the table
    (table_at,) = struct.unpack_from("<q", packed)
    return table, table_at - 8


def _warn_more(path: Path, n_points: int, held: str) -> None:
    logger.warning(
        "%s: the LAZ header announces %d points but %s; only the announced %d "
        "were read. If points are missing, export the file again.",
        path.name,
        n_points,
        held,
        n_points,
    )


def lazrs_backends() -> tuple[Any, ...]:
    """Return the backends laspy may use in this process: lazrs only.

    laspy falls back to its laszip backend when lazrs cannot open a file, and
    laszip crashes the process on truncated files: it only runs in a child.
    """
    import laspy

    return (laspy.LazBackend.LazrsParallel, laspy.LazBackend.Lazrs)


def needs_laszip(path: Path, info: LazInfo | None) -> bool:
    """Tell whether the file needs the laszip backend (refuse when it is missing)."""
    import laspy

    if info is None or not info.needs_laszip:
        return False
    if laspy.LazBackend.Laszip.is_available():
        return True
    raise InvalidInput(
        f"{path} was compressed by {info.describe()} without a chunk table, which "
        "the installed LAZ decoder (lazrs) cannot read. Install the 'laszip' "
        "package (pip install laszip), or convert the file once with "
        "'laszip -i FILE -o NEW.laz' or 'pdal translate FILE NEW.laz'."
    )


_CHILD = """
import sys, laspy
las = laspy.read(sys.argv[1], laz_backend=laspy.LazBackend.Laszip)
las.write(sys.argv[2], do_compress=False)
"""
_CHILD_TIMEOUT_S = 600


def decompress_in_child(path: Path, out: Path) -> None:
    """Decompress ``path`` into the uncompressed LAS ``out`` with laszip, in a child.

    The laszip library crashes the process (segmentation fault) on truncated
    files; in a child process the crash becomes a refusal.
    """
    import subprocess

    try:
        proc = subprocess.run(
            [sys.executable, "-c", _CHILD, str(path), str(out)],
            capture_output=True,
            text=True,
            timeout=_CHILD_TIMEOUT_S,
            check=False,
        )
    except subprocess.TimeoutExpired as exc:
        raise InvalidInput(
            f"{path}: the LAZ decoder (laszip) did not finish in "
            f"{_CHILD_TIMEOUT_S} s; the file is corrupt. Copy or export it again."
        ) from exc
    if proc.returncode != 0:
        lines = proc.stderr.strip().splitlines()
        why = lines[-1] if proc.returncode > 0 and lines else "it crashed"
        raise InvalidInput(
            f"{path} is corrupt or truncated: the LAZ decoder (laszip) failed "
            f"({why[:100]}). Copy or export it again."
        )


def is_panic(exc: BaseException) -> bool:
    """Tell whether ``exc`` is a Rust panic raised through pyo3 (a BaseException)."""
    return type(exc).__name__ == "PanicException"


@contextlib.contextmanager
def quiet_decoders() -> Iterator[None]:
    """Silence laspy's log lines and native stderr output while decoding.

    laspy logs ``ERROR: ...`` once per backend it tries before raising, and a Rust
    panic prints its message and backtrace on file descriptor 2. The error itself
    still reaches the caller as an exception. Nested and concurrent uses share one
    redirection (the first in redirects, the last out restores).
    """
    global _quiet_depth, _saved_fd
    laspy_log = logging.getLogger("laspy")
    with _quiet_lock:
        if _quiet_depth == 0:
            _saved_fd = _redirect_stderr()
        _quiet_depth += 1
    old_disabled, laspy_log.disabled = laspy_log.disabled, True
    try:
        yield
    finally:
        laspy_log.disabled = old_disabled
        with _quiet_lock:
            _quiet_depth -= 1
            if _quiet_depth == 0 and _saved_fd is not None:
                with contextlib.suppress(OSError, ValueError):
                    sys.stderr.flush()
                    os.dup2(_saved_fd, 2)
                os.close(_saved_fd)
                _saved_fd = None


def _redirect_stderr() -> int | None:
    try:
        sys.stderr.flush()
        saved = os.dup(2)
    except (OSError, ValueError, AttributeError):  # no file descriptor 2
        return None
    devnull = os.open(os.devnull, os.O_WRONLY)
    try:
        os.dup2(devnull, 2)
    finally:
        os.close(devnull)
    return saved
