"""Check an output folder path before any long work (can files be written there?).

Used for ``register --out``, ``simulate --out``, the app's export folder. Every failure
is one line naming the path and what to do; a folder on the way that the user may not
enter is said so (not "Internal error: PermissionError"), and nothing is left behind.
"""

from __future__ import annotations

import contextlib
import errno
import os
import stat
import tempfile
from pathlib import Path
from typing import TYPE_CHECKING

from amrst.errors import InvalidInput

if TYPE_CHECKING:
    from collections.abc import Iterable


def _lstat_kind(path: Path, what: str) -> int | None:
    """Return the mode of ``path`` (links followed), None when missing; or refuse."""
    try:
        return os.stat(path).st_mode
    except FileNotFoundError:
        return None
    except OSError as exc:
        if exc.errno == errno.ENOTDIR:
            return None  # a file on the way: reported by the parent walk
        if exc.errno == errno.ELOOP:
            raise InvalidInput(
                f"The {what} {path} is a symbolic link that leads back to itself (a "
                "loop). Remove the link or choose another folder."
            ) from exc
        if exc.errno in (errno.EACCES, errno.EPERM):
            raise InvalidInput(
                f"Cannot use the {what} {path}: permission denied on a folder on its "
                "path. Choose a folder you may write in (or ask for access)."
            ) from exc
        raise InvalidInput(
            f"Cannot use the {what} {path}: {exc.strerror or exc}. Choose another "
            "folder."
        ) from exc


def check_output_folder(
    out_dir: str | os.PathLike[str],
    what: str = "export folder",
    names: Iterable[str] = (),
) -> Path:
    """Check that ``out_dir`` is, or can become, a folder this process can write in.

    The folder may be missing: it is created to try writing in it, then removed again
    (with any parents created for it), so nothing is left behind.

    Parameters
    ----------
    out_dir : path
    what : str
        How messages name it ("export folder", "case folder").
    names : iterable of str
        File names to be written there; none of them may be a folder.

    Returns
    -------
    Path
        ``out_dir`` as a Path.

    Raises
    ------
    InvalidInput
        Empty path, an existing file or other non-folder, a link loop, a folder on
        the way that is a file or may not be entered, or a folder that cannot be
        created or written; or a file name taken by a folder.
    """
    if not os.fspath(out_dir).strip():
        raise InvalidInput(
            f"The {what} path is empty; give a folder name (it is created when "
            "missing)."
        )
    if "\x00" in os.fspath(out_dir):
        raise InvalidInput(
            f"The {what} path holds a NUL character, which no file name may hold; "
            "type the folder's name again."
        )
    out = Path(out_dir)
    mode = _lstat_kind(out, what)
    if mode is not None and not stat.S_ISDIR(mode):
        kind = "an existing file" if stat.S_ISREG(mode) else "not a folder"
        raise InvalidInput(
            f"The {what} {out} is {kind}; choose a folder (it is created when missing)."
        )
    missing = []
    parent = out
    while mode is None and parent != parent.parent:
        missing.append(parent)
        parent = parent.parent
        mode = _lstat_kind(parent, what)
    if mode is not None and not stat.S_ISDIR(mode):
        raise InvalidInput(
            f"Cannot create the {what} {out}: {parent} is a file, not a folder. "
            "Choose another folder."
        )
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        _remove_empty(missing)
        raise InvalidInput(
            f"Cannot create the {what} {out}: {exc.strerror or exc}. Choose "
            "another folder."
        ) from exc
    try:
        fd, probe = tempfile.mkstemp(prefix=".amrst-probe-", dir=out)
        os.close(fd)
        os.unlink(probe)
    except OSError as exc:
        raise InvalidInput(
            f"Cannot write in the {what} {out}: {exc.strerror or exc}. Check "
            "its permissions or choose another folder."
        ) from exc
    finally:
        _remove_empty(missing)
    for name in names:
        if (out / name).is_dir():
            raise InvalidInput(
                f"Cannot write {out / name}: a folder has that name. Remove or rename "
                "it, or choose another folder."
            )
    return out


def _remove_empty(folders: list[Path]) -> None:
    """Remove the folders ``check_output_folder`` created (deepest first), if empty."""
    for folder in folders:
        with contextlib.suppress(OSError):
            folder.rmdir()


def same_file(a: str | os.PathLike[str], b: str | os.PathLike[str]) -> bool:
    """Tell whether two paths name one file (the same path, a link, a hard link)."""
    try:
        return os.path.samefile(a, b)
    except OSError:
        try:
            return Path(a).resolve() == Path(b).resolve()
        except RuntimeError:  # a symbolic link loop: the readers refuse it in words
            return False


def check_outside(
    out_dir: str | os.PathLike[str], input_dir: str | os.PathLike[str], what: str
) -> None:
    """Refuse an output folder that is ``input_dir`` or lies inside it.

    Parameters
    ----------
    out_dir : path
    input_dir : path
        The folder a command reads.
    what : str
        How the message names ``input_dir`` ("case folder").

    Raises
    ------
    InvalidInput
        If ``out_dir`` is ``input_dir`` or inside it (links followed).
    """
    try:
        out, source = Path(out_dir).resolve(), Path(input_dir).resolve()
    except (OSError, RuntimeError):  # a link loop: the checks of each path say so
        return
    if out == source or source in out.parents:
        where = "is" if out == source else "lies inside"
        raise InvalidInput(
            f"The output folder {out_dir} {where} the {what} {input_dir}: the "
            "results would mix with what is read; choose a folder outside it."
        )
