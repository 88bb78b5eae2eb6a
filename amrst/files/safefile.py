"""Open a small input file (parameters, truth) only once it is known to be one.

A path argument can name a FIFO (reading blocks forever), a device such as /dev/zero
(reading never ends), a socket, a symbolic-link loop, a folder, a file behind a folder
the user may not enter, or a huge file. Each gets its own one-line message before
anything is read, and the file is opened without blocking and checked again on the open
descriptor, so it cannot change between the check and the read.
"""

from __future__ import annotations

import errno
import json
import os
import stat
from pathlib import Path
from typing import Any

from amrst.errors import InvalidInput

MAX_JSON_BYTES = 10_000_000  # parameter and truth files are a few kB

_KINDS = (
    (
        stat.S_ISFIFO,
        "a named pipe (FIFO), not a file; reading it could wait forever",
    ),
    (stat.S_ISCHR, "a character device (like /dev/zero), not a file"),
    (stat.S_ISBLK, "a block device (a disk), not a file"),
    (stat.S_ISSOCK, "a socket, not a file"),
)


def refuse_undecodable(path: str | os.PathLike[str], then: str = "") -> None:
    r"""Refuse a path that is not UTF-8 text (bytes of an old or foreign encoding).

    The results, reports, tables and manifests that name a file could not write it.
    The message shows its bad bytes as ``\xNN``; ``then`` is said after "rename it".
    """
    try:
        os.fspath(path).encode("utf-8")
    except UnicodeEncodeError:
        shown = os.fsencode(path).decode("utf-8", "backslashreplace")
        raise InvalidInput(
            f"{shown}: this name is not UTF-8 text (an old or foreign encoding); "
            f"rename it{then}."
        ) from None


def _refuse_kind(mode: int, what: str, path: Path, hint: str) -> None:
    if stat.S_ISDIR(mode):
        raise InvalidInput(f"The {what} {path} is a folder; give {hint}.")
    for test, text in _KINDS:
        if test(mode):
            raise InvalidInput(f"The {what} {path} is {text}. Give {hint}.")
    if not stat.S_ISREG(mode):  # pragma: no cover - every kind is listed above
        raise InvalidInput(f"The {what} {path} is not a regular file. Give {hint}.")


def _os_error(exc: OSError, what: str, path: Path, hint: str) -> InvalidInput:
    """One line for an OSError met while looking at or opening ``path``."""
    code = exc.errno
    if code == errno.ENOENT:
        return InvalidInput(
            f"The {what} {path} was not found. Check the path and the file name."
        )
    if code == errno.ELOOP:
        return InvalidInput(
            f"The {what} {path} is a symbolic link that leads back to itself (a "
            f"loop). Point it at a real file, or give {hint}."
        )
    if code == errno.ENOTDIR:
        return InvalidInput(
            f"The {what} {path} cannot exist: a part of its path is a file, not a "
            "folder. Check the path."
        )
    if code in (errno.EACCES, errno.EPERM):
        return InvalidInput(
            f"Permission denied reading the {what} {path} (the file, or a folder on "
            "its path, is not readable by you). Fix the permissions or copy the file "
            "somewhere you can read."
        )
    if code == errno.ENAMETOOLONG:
        return InvalidInput(
            f"The {what} path is too long ({len(str(path))} characters: "
            f"{str(path)[:60]}...); give a shorter path."
        )
    return InvalidInput(
        f"Cannot read the {what} {path}: {exc.strerror or exc}. Give {hint}."
    )


def read_small_file(
    path: str | os.PathLike[str], what: str, hint: str, max_bytes: int = MAX_JSON_BYTES
) -> bytes:
    """Read a regular file of at most ``max_bytes`` bytes, or say why not.

    Parameters
    ----------
    path : path
    what : str
        How messages name the file, e.g. "truth file".
    hint : str
        What to give instead, e.g. "a JSON file with a 4x4 'T_target_source'".
    max_bytes : int

    Returns
    -------
    bytes

    Raises
    ------
    InvalidInput
        Empty path, missing, a loop, a folder, FIFO, device or socket, no permission,
        or too large.
    """
    if not os.fspath(path).strip():
        raise InvalidInput(f"The {what} path is empty; give {hint}.")
    p = Path(path)
    try:
        _refuse_kind(os.stat(p).st_mode, what, p, hint)
        flags = os.O_RDONLY | getattr(os, "O_NONBLOCK", 0) | getattr(os, "O_NOCTTY", 0)
        fd = os.open(p, flags)
    except OSError as exc:
        raise _os_error(exc, what, p, hint) from exc
    try:
        st = os.fstat(fd)
        _refuse_kind(st.st_mode, what, p, hint)  # swapped after the first look
        if st.st_size > max_bytes:
            raise InvalidInput(
                f"The {what} {p} is {st.st_size / 1e6:.1f} MB; such a file is a few "
                f"kB (at most {max_bytes / 1e6:g} MB is read). Check that you gave "
                "the right file."
            )
        chunks, total = [], 0
        while total <= max_bytes:
            chunk = os.read(fd, min(1 << 20, max_bytes + 1 - total))
            if not chunk:
                break
            chunks.append(chunk)
            total += len(chunk)
        if total > max_bytes:
            raise InvalidInput(
                f"The {what} {p} holds more than {max_bytes / 1e6:g} MB; such a file "
                "is a few kB. Check that you gave the right file."
            )
        return b"".join(chunks)
    except OSError as exc:
        raise _os_error(exc, what, p, hint) from exc
    finally:
        os.close(fd)


def load_json_file(
    path: str | os.PathLike[str], what: str, hint: str, max_bytes: int = MAX_JSON_BYTES
) -> Any:
    """Read and decode a small JSON file, with one clear line for every failure.

    Raises
    ------
    InvalidInput
        Everything :func:`read_small_file` refuses, text that is not UTF-8, invalid
        JSON, brackets nested too deep, numbers with thousands of digits.
    """
    raw = read_small_file(path, what, hint, max_bytes)
    p = Path(path)
    try:
        text = raw.decode("utf-8-sig")
    except UnicodeDecodeError as exc:
        raise InvalidInput(
            f"The {what} {p} is not UTF-8 text (byte {exc.start}); give {hint}."
        ) from None
    try:
        return json.loads(text)
    except json.JSONDecodeError as exc:
        raise InvalidInput(
            f"The {what} {p} is not valid JSON ({exc.msg} at line {exc.lineno}, "
            f"column {exc.colno}); it must be JSON: fix it there, or give {hint}."
        ) from None
    except RecursionError:
        raise InvalidInput(
            f"The {what} {p} nests brackets thousands deep, which no {what} does. "
            f"Give {hint}."
        ) from None
    except ValueError as exc:  # e.g. an integer of more than 4300 digits
        raise InvalidInput(
            f"The {what} {p} holds a value JSON cannot be read as ({exc}); numbers "
            f"must be plain decimals. Give {hint}."
        ) from None
