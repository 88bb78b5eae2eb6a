"""Leica PTX files (ASCII, several scans per file); private to amrst.io.

Each scan is a 10-line header and then ``columns * rows`` point lines::

    columns
    rows
    sx sy sz            scanner position (registered frame)
    ax ay az            scanner x axis
    bx by bz            scanner y axis
    cx cy cz            scanner z axis
    r11 r21 r31 0       the 4x4 T_world_scanner, stored transposed: the rotation's
    r12 r22 r32 0       columns as rows, and the translation in the last row
    r13 r23 r33 0
    tx ty tz 1
    x y z intensity [r g b]      scanner-frame coordinates; "0 0 0" = no return

Points without a return (all coordinates exactly 0) are dropped. Intensity is kept as
written (0..1), colour as ``red``/``green``/``blue`` uint8. Poses come from the 4x4
matrix; a file whose matrix is the identity but whose scanner position is not (some
exporters write points already registered) keeps its points as they are, and its
scanner where the header puts it.
"""

from __future__ import annotations

import itertools
import warnings
from typing import TYPE_CHECKING, NoReturn, TextIO

import numpy as np

from amrst.errors import InvalidInput
from amrst.io.common import shorten
from amrst.io.posed import ScanInfo, check_indices, guarded, posed_raw, read_all_posed
from amrst.types import MAX_COORD_M

if TYPE_CHECKING:
    from collections.abc import Callable, Generator, Sequence
    from pathlib import Path

    from amrst.io.common import RawCloud

LABEL = "ptx"
_HEADER_LINES = 10
_MIN_LINE_BYTES = 6  # "0 0 0\n", the shortest point line
# A scan of more points than any scanner makes (a 0.01 deg grid is 1.3e9): corrupt.
_MAX_SCAN_POINTS = 10**11


class _Scan:
    """Where one scan's lines are, and its header values."""

    def __init__(
        self, start: int, n: int, T: np.ndarray, width: int, scanner: np.ndarray
    ) -> None:
        self.start, self.n, self.T, self.width = start, n, T, width
        self.scanner = scanner  # (3,) the header's scanner position


def _numbers(line: str, count: int, path: Path, line_no: int) -> list[float]:
    parts = line.split()
    try:
        values = [float(p) for p in parts]
    except ValueError:
        values = []
    if len(values) != count:
        raise InvalidInput(
            f"{path}, line {line_no}: expected {count} number(s) of a PTX scan "
            f"header, found {shorten(line.strip(), 60)!r}. The file is corrupt, "
            "truncated or not a PTX file; export it again."
        )
    return values


def _walk(
    path: Path, keep: Callable[[int], bool]
) -> Generator[tuple[_Scan, np.ndarray | None], None, None]:
    """Walk the file's scans in order: each one's header and, when ``keep(i)``, points.

    The points are the scan's rows, ``n x width``. The file is read a line at a time:
    memory holds the numbers of the scan kept, parsed by numpy's C reader, never a
    scan's lines as strings (a Python string a line costs ten times its numbers).
    """
    with path.open(encoding="ascii", errors="strict") as fh:
        pos, i = 0, 0  # lines read, scans walked
        for line in fh:
            pos += 1
            if not line.strip():
                continue
            header = [line, *itertools.islice(fh, _HEADER_LINES - 1)]
            if len(header) < _HEADER_LINES:
                raise InvalidInput(
                    f"{path} ends inside the header of scan {i} (line {pos}): the file "
                    "is truncated. Export it again."
                )
            scan = _header(header, pos, path)
            pos += _HEADER_LINES - 1
            points = _points(fh, scan, path) if keep(i) else None
            if points is None:
                _skip(fh, scan, path)
            pos += scan.n
            yield scan, points
            i += 1


def _skip(fh: TextIO, scan: _Scan, path: Path) -> None:
    """Read past a scan's point lines, checking their count and the first's width."""
    if not scan.n:
        return
    first = next(fh, "")
    if not first:
        _truncated(scan, 0, path)
    _set_width(scan, len(first.split()), path)
    read = 1 + sum(1 for _ in itertools.islice(fh, scan.n - 1))
    if read < scan.n:
        _truncated(scan, read, path)


def _set_width(scan: _Scan, width: int, path: Path) -> None:
    if width not in (3, 4, 7):
        raise InvalidInput(
            f"{path}, line {scan.start + 1}: a PTX point line has 3, 4 or 7 "
            f"numbers (x y z [intensity [r g b]]), found {width}."
        )
    scan.width = width


def _truncated(scan: _Scan, read: int | None, path: Path) -> NoReturn:
    """Refuse a scan the file ends inside (``read``: its lines there, None: unknown)."""
    ends = "is too short to hold them" if read is None else f"ends after {read}"
    raise InvalidInput(
        f"{path}: the scan starting at line {scan.start + 1} declares {scan.n} points "
        f"but the file {ends}: it is truncated. Export it again."
    )


def _header(lines: list[str], first: int, path: Path) -> _Scan:
    """Read a scan's 10 header lines, the first of them line ``first`` (from 1)."""
    cols = _numbers(lines[0], 1, path, first)[0]
    rows = _numbers(lines[1], 1, path, first + 1)[0]
    if cols < 0 or rows < 0 or cols != int(cols) or rows != int(rows):
        raise InvalidInput(
            f"{path}, line {first}: the scan size {cols:g} x {rows:g} is not "
            "two whole numbers. The file is corrupt or not a PTX file."
        )
    if cols * rows > _MAX_SCAN_POINTS:
        raise InvalidInput(
            f"{path}, line {first}: the scan size {cols:g} x {rows:g} is more points "
            "than a scan holds. The file is corrupt or not a PTX file."
        )
    scanner = np.array(_numbers(lines[2], 3, path, first + 2))
    for k in range(3, 6):
        _numbers(lines[k], 3, path, first + k)
    M = np.array([_numbers(lines[k], 4, path, first + k) for k in range(6, 10)])
    T = M.T.copy()  # stored transposed: translation in the last row
    start = first - 1 + _HEADER_LINES  # its first point line, from 0
    return _Scan(start, int(cols) * int(rows), T, 4, scanner)


def _scanner_said(scan: _Scan) -> tuple[float, float, float] | None:
    """Where the header puts the scanner, or None when it does not say.

    The pose's position; for points written already registered (an identity
    matrix), the scanner line's.
    """
    if not np.allclose(scan.T, np.eye(4)):
        return (float(scan.T[0, 3]), float(scan.T[1, 3]), float(scan.T[2, 3]))
    if scan.scanner.any():
        return (float(scan.scanner[0]), float(scan.scanner[1]), float(scan.scanner[2]))
    return None


def list_scans(path: Path) -> list[ScanInfo]:
    """Every scan of the file, from its headers."""

    def run() -> list[ScanInfo]:
        scans = [scan for scan, _ in _walk(path, lambda _i: False)]
        fields = {3: (), 4: ("intensity",), 7: ("intensity", "red", "green", "blue")}
        return [
            ScanInfo(
                i,
                "",  # PTX does not name its scans
                s.n,
                s.T,
                not np.allclose(s.T, np.eye(4)),
                fields[s.width],
                _scanner_said(s),
            )
            for i, s in enumerate(scans)
        ]

    result: list[ScanInfo] = guarded(path, LABEL, run)
    return result


def _points(fh: TextIO, scan: _Scan, path: Path) -> np.ndarray:
    """Parse a scan's point lines from ``fh``, which is left after its last one."""
    if not scan.n:
        return np.zeros((0, 4))
    if scan.n > path.stat().st_size // _MIN_LINE_BYTES:
        # Told before its lines run on into the next scan's header.
        _truncated(scan, None, path)
    with warnings.catch_warnings():
        # An empty scan is told below, as a truncated file, not as numpy's warning.
        warnings.filterwarnings("ignore", message=".*input contained no data")
        try:
            # Its n lines exactly: numpy skips a blank one, which then shows as a row
            # too few, and never reads into the next scan's header.
            values = np.loadtxt(
                itertools.islice(fh, scan.n), dtype=np.float64, comments=None, ndmin=2
            )
        except ValueError as exc:
            raise InvalidInput(
                f"{path}: a point line of the scan starting at line {scan.start + 1} "
                f"is not 3, 4 or 7 numbers like the others ({_reason(exc)}). The file "
                "is corrupt; export it again."
            ) from exc
    if len(values) < scan.n:
        if next(fh, None) is None:
            _truncated(scan, len(values), path)
        raise InvalidInput(
            f"{path}: a blank line among the point lines of the scan starting at line "
            f"{scan.start + 1}. The file is corrupt; export it again."
        )
    _set_width(scan, values.shape[1], path)
    return values


def _reason(exc: ValueError) -> str:
    """Numpy's parse error without its advice to the programmer (after a ';')."""
    return shorten(str(exc).split(";")[0].rstrip(". "), 80)


def read_raw_scans(
    path: Path, wanted: Sequence[int] | None, posed: bool
) -> list[tuple[int, RawCloud]]:
    """Read the chosen scans (all when None) as ``(index, RawCloud)``, posed or not."""

    def run() -> list[tuple[int, RawCloud]]:
        chosen = None if wanted is None else set(wanted)
        walker = _walk(path, lambda i: chosen is None or i in chosen)
        # Up to the last scan asked for: the scans after it are not walked through.
        last = None if chosen is None else max(chosen, default=-1) + 1
        try:
            walked = list(itertools.islice(walker, last))
        finally:
            walker.close()
        scans = [scan for scan, _ in walked]
        out = []
        for i in check_indices(path, wanted, len(scans)):
            pts = walked[i][1]
            assert pts is not None  # kept: a scan asked for
            keep = np.any(pts[:, :3] != 0.0, axis=1)  # 0 0 0: no return
            pts = pts[keep]
            attributes: dict[str, np.ndarray] = {}
            if scans[i].width >= 4:
                attributes["intensity"] = pts[:, 3].astype(np.float32)
            if scans[i].width == 7:
                for j, name in enumerate(("red", "green", "blue")):
                    attributes[name] = np.clip(pts[:, 4 + j], 0, 255).astype(np.uint8)
            meta = {"scan_index": i, "n_no_return": int((~keep).sum())}
            at = f"{path}, the scan starting at line {scans[i].start - _HEADER_LINES + 1}"
            raw = posed_raw(
                pts[:, :3], scans[i].T, attributes, meta, posed=posed, where=at
            )
            if np.allclose(scans[i].T, np.eye(4)) and scans[i].scanner.any():
                # Points written already registered: the scanner is the header's.
                if not np.abs(scans[i].scanner).max() <= MAX_COORD_M:  # NaN too
                    raise InvalidInput(
                        f"{at}: its scanner position is not three numbers within "
                        f"{MAX_COORD_M:g} m. The file is corrupt; export it again."
                    )
                where = tuple(float(v) for v in scans[i].scanner)
                raw = raw._replace(meta={**raw.meta, "scanner_origin": where})
            out.append((i, raw))
        return out

    result: list[tuple[int, RawCloud]] = guarded(path, LABEL, run)
    return result


def read_ptx(path: Path) -> RawCloud:
    """Every scan of the file, posed, in one cloud (``scan_id`` when more than one)."""
    return read_all_posed(read_raw_scans, path)
