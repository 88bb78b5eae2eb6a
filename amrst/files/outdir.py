"""Replace the files of an output folder as one unit, whatever instant a run is killed.

``replace_files(folder, writers)`` writes every new file first, then switches the whole
set with ONE atomic step. Two ways, chosen per run:

**Swap** (the folder holds nothing but AMRST outputs; Linux ``renameat2``): the new set
is built in a sibling folder ``.<name>.amrst-swap-<random>`` (the earlier files that
this run keeps are hard-linked into it), then the two folders are exchanged with
``RENAME_EXCHANGE``, and the sibling, which now holds the old set, is deleted.

=============================  =================================================
killed while ...               the output folder holds
=============================  =================================================
writing the new set            the complete old set (+ the sibling, debris)
the exchange                   it is atomic: old or new, never both
deleting the old set           the complete new set (+ the sibling, debris)
=============================  =================================================

**Journal** (the folder also holds other files, is a mount point or the working
directory, its parent is not writable, or the exchange is not supported): the new files
are staged in ``<folder>/.amrst-export-<random>``; a commit record
``.amrst-commit.json`` is written atomically once they are all there, and only then are
they renamed into place. Killed before the record: the old set is intact. Killed after
it (a few renames, milliseconds): the folder can show a mix *until the next AMRST run
that writes it*, which finishes the renames from the record before anything else.

Either way the next run removes the debris (staging folders, siblings, records) under
the folder's lock (amrst.files.folderlock), so two writers never interleave.
"""

from __future__ import annotations

import contextlib
import ctypes
import errno
import json
import logging
import os
import shutil
import tempfile
from pathlib import Path
from typing import TYPE_CHECKING

from amrst.errors import AmrstError, InvalidInput
from amrst.files.atomic import write_json_atomic
from amrst.files.folderlock import (
    DEFAULT_TIMEOUT_S,
    LOCK_NAME,
    FolderBusy,
    FolderLock,
    holder_alive,
)

if TYPE_CHECKING:
    from collections.abc import Callable, Collection, Iterable, Mapping

logger = logging.getLogger(__name__)

HIDDEN_PREFIX = ".amrst-"  # every file of ours in an output folder starts so
STAGE_PREFIX = ".amrst-export-"
COMMIT_NAME = ".amrst-commit.json"
OLD_SET_NAME = ".amrst-old-set.json"  # the names a swap may delete with the old set
_RENAME_EXCHANGE = 2


def swap_prefix(folder: Path) -> str:
    """Name prefix of the sibling folders a swap builds next to ``folder``."""
    return f".{folder.name}.amrst-swap-"


def _libc_renameat2() -> Callable[..., int] | None:
    try:
        libc = ctypes.CDLL(None, use_errno=True)
    except OSError:  # pragma: no cover - no C library to load
        return None
    return getattr(libc, "renameat2", None)


_RENAMEAT2 = _libc_renameat2()


def exchange(a: Path, b: Path) -> None:
    """Swap two folders atomically (Linux ``renameat2(RENAME_EXCHANGE)``).

    Raises
    ------
    OSError
        ENOSYS/EINVAL when the system or the file system cannot.
    """
    if _RENAMEAT2 is None:
        raise OSError(errno.ENOSYS, "renameat2 is not available")
    at_fdcwd = -100
    if _RENAMEAT2(at_fdcwd, os.fsencode(a), at_fdcwd, os.fsencode(b), _RENAME_EXCHANGE):
        code = ctypes.get_errno()
        raise OSError(code, os.strerror(code), str(a))


def _fsync(path: Path) -> None:
    """Flush a file or folder to disk (a power cut then keeps what a kill keeps)."""
    with contextlib.suppress(OSError):
        fd = os.open(path, os.O_RDONLY)
        try:
            os.fsync(fd)
        finally:
            os.close(fd)


def _is_ours(name: str) -> bool:
    return name.startswith(HIDDEN_PREFIX)


def _plain(name: str) -> bool:
    """Tell whether ``name`` may be a file of the set.

    Relative and inside the folder (a subfolder allowed, e.g. ``trees/T001.ply``), and
    not one of ours.
    """
    parts = str(name).split("/")
    return (
        not os.path.isabs(name)
        and all(p not in ("", ".", "..") for p in parts)
        and not _is_ours(parts[0])
    )


class FolderChanged(InvalidInput):
    """Another run wrote the output folder while this one worked: nothing written."""


#: What an output folder held of some names when a run began (:func:`folder_stamp`).
FolderStamp = dict[str, tuple[int, int, int] | None]


def folder_stamp(folder: str | os.PathLike[str], names: Iterable[str]) -> FolderStamp:
    """Say what ``folder`` holds under ``names``: inode, size, modification time.

    None where an entry is missing. A run takes it before its long work and hands it
    to :func:`replace_files`, which refuses to write when the folder no longer
    matches: another run wrote it meanwhile, and replacing that run's files would lose
    them without a word.
    """
    stamp: FolderStamp = {}
    for name in sorted(set(names)):
        try:
            st = os.lstat(Path(folder) / name)
        except OSError:
            stamp[name] = None
        else:
            stamp[name] = (st.st_ino, st.st_size, st.st_mtime_ns)
    return stamp


def replace_files(
    folder: str | os.PathLike[str],
    writers: Mapping[str, Callable[[Path], object]],
    *,
    managed: Collection[str],
    remove: Iterable[str] = (),
    lock_timeout_s: float = DEFAULT_TIMEOUT_S,
    unchanged: FolderStamp | None = None,
) -> tuple[list[Path], list[str]]:
    """Write ``writers`` into ``folder`` and remove ``remove``, as one unit.

    Parameters
    ----------
    folder : path
        The output folder; created when missing.
    writers : dict of str to callable
        File name -> ``write(path)`` that writes that file at ``path``.
    managed : collection of str
        Every file name this kind of output may hold; other entries make the folder
        "shared" (journal mode).
    remove : iterable of str
        Names of earlier files to drop from the set (if present).
    lock_timeout_s : float
        How long to wait for another writer of the folder.
    unchanged : FolderStamp or None
        What the folder held when the run began (:func:`folder_stamp`): nothing is
        written when it holds something else now.

    Returns
    -------
    (list of Path, list of str)
        The files written, and the names removed.

    Raises
    ------
    AmrstError
        A write failed: the folder keeps its old set (and no debris of this run).
    FolderBusy
        Another writer kept the folder for ``lock_timeout_s``.
    FolderChanged
        The folder no longer holds what ``unchanged`` says.
    """
    out = Path(folder)
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise InvalidInput(
            f"Cannot create the output folder {out}: {exc.strerror or exc}. Choose "
            "another folder."
        ) from exc
    real = Path(os.path.realpath(out))
    with FolderLock(real, lock_timeout_s) as lock:
        recover(real)
        if unchanged is not None and folder_stamp(real, unchanged) != unchanged:
            raise FolderChanged(
                f"{out} changed while this run worked (another run wrote it): nothing "
                "was written. Look at what it holds, then run again (or choose "
                "another folder)."
            )
        gone = [n for n in dict.fromkeys(remove) if n not in writers]
        gone = [n for n in gone if os.path.lexists(real / n)]
        if _can_swap(real, managed):
            try:
                _swap(real, out, writers, gone, lock)
            except _NoExchange as exc:
                _journal(real, out, writers, gone, exc.stage)
        else:
            _journal(real, out, writers, gone, None)
    return [out / name for name in writers], gone


class _NoExchange(Exception):
    """The file system refused the exchange; the staged set is handed to the journal."""

    def __init__(self, stage: Path) -> None:
        super().__init__(str(stage))
        self.stage = stage


def _can_swap(real: Path, managed: Collection[str]) -> bool:
    if _RENAMEAT2 is None or os.path.ismount(real):
        return False
    parent = real.parent
    if not os.access(parent, os.W_OK | os.X_OK):
        return False
    with contextlib.suppress(OSError):
        if os.path.samefile(os.getcwd(), real):
            return False  # a shell sitting in it would be left in the deleted old set
    with os.scandir(real) as it:
        for entry in it:
            if _is_ours(entry.name):
                continue
            if entry.name not in managed or not entry.is_file(follow_symlinks=False):
                return False
    return True


def _write_into(
    stage: Path, shown: Path, writers: Mapping[str, Callable[[Path], object]]
) -> None:
    """Write every file into ``stage``; errors name ``shown`` (the real folder)."""
    for name, write in writers.items():
        try:
            write(stage / name)
        except AmrstError as exc:
            raise type(exc)(str(exc).replace(str(stage), str(shown))) from exc
        except Exception as exc:
            raise AmrstError(
                f"Could not write {shown / name}: {exc} ({type(exc).__name__}). "
                "Nothing was changed; check the free disk space and the permissions, "
                "then retry."
            ) from exc
        _fsync(stage / name)
    _fsync(stage)


def _swap(
    real: Path,
    shown: Path,
    writers: Mapping[str, Callable[[Path], object]],
    gone: list[str],
    lock: FolderLock,
) -> None:
    parent = real.parent
    new = Path(tempfile.mkdtemp(prefix=swap_prefix(real), dir=parent))
    try:
        os.chmod(new, real.stat().st_mode & 0o7777)
        lock.adopt(new / LOCK_NAME)
        with os.scandir(real) as it:
            old_names = [e.name for e in it if not _is_ours(e.name)]
        kept = [n for n in old_names if n not in writers and n not in gone]
        for name in kept:  # earlier outputs this run leaves as they are
            try:
                os.link(real / name, new / name)
            except OSError:
                shutil.copy2(real / name, new / name)
        _write_into(new, shown, writers)
        write_json_atomic(real / OLD_SET_NAME, old_names)
        try:
            exchange(new, real)  # the commit: one atomic step
        except OSError as exc:
            if exc.errno not in (errno.ENOSYS, errno.EINVAL, errno.EPERM, errno.EXDEV):
                raise
            raise _NoExchange(_hand_over(new, real)) from exc
    except _NoExchange:
        raise
    except BaseException:
        shutil.rmtree(new, ignore_errors=True)
        raise
    _fsync(parent)
    discard_old_set(new, real)


def _hand_over(new: Path, real: Path) -> Path:
    """Move a staged swap folder into ``real`` as a journal staging folder."""
    stage = real / f"{STAGE_PREFIX}{new.name.rsplit('-', 1)[-1]}"
    (new / LOCK_NAME).unlink(missing_ok=True)
    (real / OLD_SET_NAME).unlink(missing_ok=True)
    os.rename(new, stage)
    return stage


def _journal(
    real: Path,
    shown: Path,
    writers: Mapping[str, Callable[[Path], object]],
    gone: list[str],
    stage: Path | None,
) -> None:
    if stage is None:
        try:
            stage = Path(tempfile.mkdtemp(prefix=STAGE_PREFIX, dir=real))
        except OSError as exc:
            raise InvalidInput(
                f"Cannot write in the output folder {shown}: {exc.strerror or exc}. "
                "Check its permissions or choose another folder."
            ) from exc
        try:
            _write_into(stage, shown, writers)
        except BaseException:
            shutil.rmtree(stage, ignore_errors=True)
            raise
    record = {"stage": stage.name, "names": list(writers), "remove": gone}
    write_json_atomic(real / COMMIT_NAME, record)  # the commit
    _roll_forward(real, record)


def _roll_forward(real: Path, record: Mapping[str, object]) -> None:
    """Finish a committed journal: rename the staged files in, drop the removed ones."""
    stage = real / str(record["stage"])
    names = record.get("names", [])
    for name in names if isinstance(names, list) else []:
        src, dst = stage / str(name), real / str(name)
        if src.exists():
            with contextlib.suppress(OSError):  # keep the permissions it replaces
                os.chmod(src, dst.stat().st_mode & 0o777)
            dst.parent.mkdir(parents=True, exist_ok=True)  # a new subfolder's file
            os.replace(src, dst)
    remove = record.get("remove", [])
    for name in remove if isinstance(remove, list) else []:
        if _plain(str(name)):
            with contextlib.suppress(FileNotFoundError):
                os.unlink(real / str(name))
            if "/" in str(name):  # a subfolder left empty goes too (rmdir: only then)
                with contextlib.suppress(OSError):
                    os.rmdir((real / str(name)).parent)
    _fsync(real)
    (real / COMMIT_NAME).unlink()
    shutil.rmtree(stage, ignore_errors=True)


def recover(folder: str | os.PathLike[str]) -> None:
    """Finish or undo what a killed run left in ``folder``; call it under the lock.

    A committed journal is rolled forward; staging folders, probe files, temporary
    commit records and swap siblings are removed (an entry that is not ours found in
    an old swap sibling is moved back into ``folder``).
    """
    real = Path(os.path.realpath(folder))
    commit = real / COMMIT_NAME
    if commit.is_file():
        try:
            record = json.loads(commit.read_text(encoding="utf-8"))
            if not isinstance(record, dict):
                raise ValueError("not an object")
            _roll_forward(real, record)
            logger.warning(
                "Finished the export into %s that an earlier run left halfway.", real
            )
        except (OSError, ValueError) as exc:
            logger.warning("Dropped an unreadable commit record in %s: %s", real, exc)
            commit.unlink(missing_ok=True)
    with os.scandir(real) as it:
        debris = [
            e.path
            for e in it
            # staging folders, probes, the old-set list and the temporary files of
            # atomic writes of ours (".<name>.<random>.tmp")
            if e.name.startswith(
                (STAGE_PREFIX, ".amrst-probe-", OLD_SET_NAME, "." + HIDDEN_PREFIX)
            )
        ]
    for path in debris:
        if os.path.isdir(path) and not os.path.islink(path):
            shutil.rmtree(path, ignore_errors=True)
        else:
            with contextlib.suppress(OSError):
                os.unlink(path)
    parent = real.parent
    with contextlib.suppress(OSError), os.scandir(parent) as it:
        siblings = [
            Path(e.path)
            for e in it
            if e.name.startswith(swap_prefix(real)) and e.is_dir(follow_symlinks=False)
        ]
        for sibling in siblings:
            discard_old_set(sibling, real)


def clear_dead_run(folder: str | os.PathLike[str]) -> None:
    """Clear the lock and the temporary files a killed run left in ``folder``.

    Only what is proved dead is touched: the lock is taken without waiting (the
    kernel lets go of a dead holder's lock at once), and a holder recorded on this
    host whose process still runs is left alone, for file systems without locks.
    A live writer's folder is left as it is; the export waits for it later.
    """
    real = Path(os.path.realpath(folder))
    lock_file = real / LOCK_NAME
    try:
        if not lock_file.is_file() or holder_alive(lock_file):
            return
    except OSError:  # a folder we may not enter: the folder check says so in words
        return
    try:
        with FolderLock(real, timeout_s=0):
            recover(real)
    except FolderBusy:
        return
    logger.info("Cleared what a stopped run left in %s.", real)


def discard_old_set(old: Path, real: Path) -> None:
    """Delete a swap sibling; anything in it that is not ours goes back into ``real``.

    A file the user dropped into the folder while it was being swapped must not be
    deleted with the old outputs: only the names listed before the swap are.
    """
    try:
        listed = set(json.loads((old / OLD_SET_NAME).read_text(encoding="utf-8")))
    except (OSError, ValueError, TypeError):
        listed = None  # killed before the list was written: the swap did not happen
    with contextlib.suppress(OSError), os.scandir(old) as it:
        for entry in it:
            if _is_ours(entry.name) or listed is None or entry.name in listed:
                continue
            with contextlib.suppress(OSError):
                if not os.path.lexists(real / entry.name):
                    os.rename(entry.path, real / entry.name)
                    logger.warning("Moved %s back into %s.", entry.name, real)
    # The list goes last: a run killed meanwhile still knows what it may delete.
    with contextlib.suppress(OSError), os.scandir(old) as it:
        for entry in it:
            if entry.name == OLD_SET_NAME:
                continue
            if entry.is_dir(follow_symlinks=False):
                shutil.rmtree(entry.path, ignore_errors=True)
            else:
                os.unlink(entry.path)
    shutil.rmtree(old, ignore_errors=True)
