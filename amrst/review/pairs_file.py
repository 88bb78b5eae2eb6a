"""Point pairs in a CSV file: picked in the app, in CloudCompare or by a survey.

One pair a row, in the files' own (world) coordinates, with the header
``target_x,target_y,target_z,source_x,source_y,source_z``; extra columns (a label, a
residual) are kept out of the fit. The same file is read by ``amrst register
--pairs`` and loaded or saved by the app's Manual pose dock.
"""

from __future__ import annotations

import csv
import io
import math
from typing import TYPE_CHECKING

import numpy as np

from amrst.errors import InvalidInput
from amrst.files.atomic import write_atomic
from amrst.types import MAX_COORD_M

if TYPE_CHECKING:
    from pathlib import Path

COLUMNS = ("target_x", "target_y", "target_z", "source_x", "source_y", "source_z")
MAX_PAIRS = 10_000


def read_pairs(path: Path) -> tuple[np.ndarray, np.ndarray]:
    """Read point pairs from a CSV file.

    Parameters
    ----------
    path : Path

    Returns
    -------
    target_pts, source_pts : (K, 3) float64
        World coordinates, one row per pair, in file order.

    Raises
    ------
    InvalidInput
        The file is missing or unreadable, lacks a column, holds a value that is not a
        finite number, or fewer than 2 pairs.
    """
    from amrst.files.safefile import read_small_file

    hint = f"a CSV file with the columns {','.join(COLUMNS)}"
    raw = read_small_file(path, "pairs file", hint)
    try:
        text = raw.decode("utf-8-sig")
    except UnicodeDecodeError as exc:
        raise InvalidInput(
            f"Cannot read the pairs file {path}: it is not UTF-8 text. Give {hint}."
        ) from exc
    reader = csv.DictReader(io.StringIO(text))
    try:
        header = {(h or "").strip() for h in (reader.fieldnames or [])}
        rows = list(reader)
    except csv.Error as exc:  # a field of over 128 KiB, a NUL byte...
        raise InvalidInput(
            f"{path.name} is not a pairs CSV ({exc}): give the columns "
            f"{','.join(COLUMNS)}, one pair a line."
        ) from exc
    missing = [c for c in COLUMNS if c not in header]
    if missing and ";" in text.partition("\n")[0]:
        raise InvalidInput(
            f"{path.name} separates its columns with ';' (a spreadsheet's regional "
            "setting): save it as CSV with commas, and '.' as the decimal point."
        )
    if missing:
        raise InvalidInput(
            f"{path.name} has no column {', '.join(missing)}: its first line must name "
            f"{','.join(COLUMNS)}."
        )
    if len(rows) > MAX_PAIRS:
        raise InvalidInput(
            f"{path.name} holds {len(rows)} pairs; at most {MAX_PAIRS} are read. "
            "Keep the pairs a technician picked."
        )
    values = np.empty((len(rows), 6))
    for i, row in enumerate(rows):
        clean = {(k or "").strip(): (v or "").strip() for k, v in row.items()}
        for j, col in enumerate(COLUMNS):
            try:
                values[i, j] = float(clean[col])
            except ValueError:
                values[i, j] = math.nan
            if not abs(values[i, j]) <= MAX_COORD_M:  # NaN too
                text = clean[col] if len(clean[col]) <= 24 else clean[col][:20] + "…"
                raise InvalidInput(
                    f"{path.name} line {i + 2}: {col} is {text!r}, not a "
                    "coordinate (a finite number within 1e9 m). Fix or delete that row."
                )
    if len(values) < 2:
        raise InvalidInput(
            f"{path.name} holds {len(values)} pair(s): give at least 2 (3 or more "
            "spread over the tree for a full rigid fit)."
        )
    return values[:, :3].copy(), values[:, 3:].copy()


def write_pairs(path: Path, target_pts: np.ndarray, source_pts: np.ndarray) -> None:
    """Write point pairs to a CSV file, atomically (world coordinates, mm precision+).

    Parameters
    ----------
    path : Path
    target_pts, source_pts : (K, 3) float64

    Raises
    ------
    InvalidInput
        When the two arrays hold different numbers of points.
    """
    t = np.asarray(target_pts, float).reshape(-1, 3)
    s = np.asarray(source_pts, float).reshape(-1, 3)
    if len(t) != len(s):
        raise InvalidInput(
            f"{len(t)} target points but {len(s)} source points: every pair needs both."
        )
    lines = [",".join(COLUMNS)]
    lines += [",".join(f"{v:.6f}" for v in (*a, *b)) for a, b in zip(t, s, strict=True)]
    text = "\n".join(lines) + "\n"
    write_atomic(path, lambda tmp: tmp.write_text(text, encoding="utf-8"))
