"""Atomic writes: every file the engine writes goes through here.

The content goes to a temporary file in the same folder, which then replaces the target
with ``os.replace``: a failed or interrupted write never leaves half a file and never
clobbers the old one. The new file keeps the old one's permissions (0644 when new;
``mkstemp`` alone would make it readable by its owner only).
"""

from __future__ import annotations

import functools
import json
import math
import os
import tempfile
from pathlib import Path
from typing import TYPE_CHECKING, Any

from amrst.errors import AmrstError

if TYPE_CHECKING:
    from collections.abc import Callable, Iterable, Mapping, Sequence


def write_atomic(
    path: str | os.PathLike[str], write_to: Callable[[Path], object]
) -> None:
    """Run ``write_to(temp_path)``, then move the temp file over ``path``.

    Raises
    ------
    AmrstError
        When the folder is not writable or the write fails (the old file is untouched).
    """
    path = Path(path)
    try:
        fd, name = tempfile.mkstemp(
            prefix=f".{path.name}.", suffix=".tmp", dir=path.parent
        )
    except OSError as exc:
        raise AmrstError(
            f"Cannot write {path}: {exc.strerror or exc}. Check that the folder exists "
            "and is writable, or choose another one."
        ) from exc
    os.close(fd)
    tmp = Path(name)
    try:
        write_to(tmp)
        mode = path.stat().st_mode & 0o777 if path.exists() else 0o644
        os.chmod(tmp, mode)
        os.replace(tmp, path)
    except BaseException as exc:
        tmp.unlink(missing_ok=True)
        if isinstance(exc, AmrstError) or not isinstance(exc, Exception):
            raise
        raise AmrstError(
            f"Could not write {path}: {exc} ({type(exc).__name__}). Nothing was "
            "changed; check the free disk space and the permissions, then retry."
        ) from exc


def write_text_atomic(path: str | os.PathLike[str], text: str | bytes) -> None:
    """Write text (UTF-8) or bytes atomically."""
    data = text.encode("utf-8") if isinstance(text, str) else text
    write_atomic(path, lambda tmp: tmp.write_bytes(data))


def text_writer(text: str | bytes) -> Callable[[Path], None]:
    """Return ``write(path)`` that writes ``text``: a file of a set (``replace_files``)."""
    return functools.partial(write_text_atomic, text=text)


def strict_json(data: Any) -> tuple[Any, dict[str, str]]:
    """Return ``data`` with every NaN/infinity replaced by None, and where they were.

    Strict JSON has no NaN or Infinity (``json.dumps`` writes them by default, and
    most other readers then refuse the file). Numpy scalars and arrays become plain
    numbers and lists; tuples become lists.

    Returns
    -------
    (object, dict of str to str)
        The clean data, and dotted path -> what the value was (``"inf"``, ``"nan"``).
    """
    nulls: dict[str, str] = {}

    def clean(value: Any, where: str) -> Any:
        if isinstance(value, dict):
            return {
                k: clean(v, f"{where}.{k}" if where else str(k))
                for k, v in value.items()
            }
        if isinstance(value, (list, tuple)):
            return [clean(v, f"{where}[{i}]") for i, v in enumerate(value)]
        if hasattr(value, "tolist") and not isinstance(value, (str, bytes)):
            return clean(value.tolist(), where)  # numpy scalars and arrays
        if isinstance(value, float) and not math.isfinite(value):
            nulls[where] = repr(value)
            return None
        return value

    return clean(data, ""), nulls


def write_json_atomic(path: str | os.PathLike[str], data: Any, indent: int = 2) -> None:
    """Write ``data`` as indented, strict JSON atomically.

    A value that is not a finite number is written ``null``; when ``data`` is an
    object, its key ``null_values`` then says which ones and what they were, so a
    reader knows why (e.g. ``{"truth.fine.translation_error_m": "inf"}``).
    """
    clean, nulls = strict_json(data)
    if nulls and isinstance(clean, dict):
        clean["null_values"] = {
            k: f"{v} (not a finite number; JSON has no NaN or infinity)"
            for k, v in nulls.items()
        }
    text = json.dumps(clean, indent=indent, allow_nan=False)
    write_text_atomic(path, text + "\n")


def make_folder(path: str | os.PathLike[str], what: str) -> Path:
    """Create the folder ``path`` (and its parents) or say why not.

    Parameters
    ----------
    path : path
    what : str
        How the message names it, e.g. "case folder".

    Returns
    -------
    Path

    Raises
    ------
    InvalidInput
        When it cannot be created (a file in the way, no permission).
    """
    from amrst.errors import InvalidInput

    out = Path(path)
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise InvalidInput(
            f"Cannot create the {what} {out}: {exc.strerror or exc}. Choose another "
            "folder."
        ) from exc
    return out


def xlsx_book(
    title: str,
    columns: Sequence[str],
    rows: Iterable[Mapping[str, Any]],
    creator: str,
) -> Any | None:
    """Return an openpyxl workbook of ``rows`` under ``columns``; None without openpyxl.

    One sheet named ``title``, a header row, the first column and the header frozen;
    ``creator`` names the program in the file's properties.
    Save it with :func:`write_atomic` (``lambda tmp: book.save(tmp)``).
    """
    try:
        import openpyxl
    except ImportError:
        return None
    book = openpyxl.Workbook()
    book.properties.creator = creator
    sheet = book.active
    sheet.title = title
    sheet.append(list(columns))
    for row in rows:
        sheet.append([row[c] for c in columns])
    sheet.freeze_panes = "B2"
    return book
