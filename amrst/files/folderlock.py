"""One writer per output folder: a lock file that names its holder.

``FolderLock(folder)`` holds an exclusive ``flock`` on ``folder/.amrst-lock`` and writes
who holds it there (pid, host, start time, command). A second writer, in this process
or another, waits for it (up to ``timeout_s``) and then gives up with a message naming
the holder. The kernel releases the lock when its holder dies, so the lock of a killed
run is stale at once and the next run takes it without asking anyone (the file it left
is reused). The folder of an export is swapped as a whole (amrst.files.outdir), so the lock
file itself can change inode: a lock is held only once the path names the very file
that was locked (the usual lock-file re-check), and ``adopt`` locks the new folder's
lock file before the swap.
"""

from __future__ import annotations

import contextlib
import datetime as _dt
import json
import logging
import os
import socket
import sys
import time
from pathlib import Path
from typing import TYPE_CHECKING

from amrst.errors import InvalidInput

if TYPE_CHECKING:
    from types import TracebackType

try:  # POSIX only; elsewhere two writers are not kept apart
    import fcntl
except ImportError:  # pragma: no cover - Windows
    fcntl = None  # type: ignore[assignment]

logger = logging.getLogger(__name__)

LOCK_NAME = ".amrst-lock"
DEFAULT_TIMEOUT_S = 300.0


class FolderBusy(InvalidInput):
    """Another writer holds the folder's lock and did not let go in time."""


def holder_text(raw: bytes) -> str:
    """Describe the holder written in a lock file, for messages."""
    try:
        info = json.loads(raw.decode("utf-8"))
        return (
            f"pid {info['pid']} on {info['host']}, started {info['started']}"
            f" ({info['command']})"
        )
    except (ValueError, KeyError, TypeError):
        return "a process that has not written its name yet"


def holder_alive(lock_file: Path) -> bool:
    """Tell whether the process a lock file names may still run.

    True when the record names another process on this host that exists; False
    for a dead process, this process, or an unreadable record. A holder on another
    host cannot be checked from here and counts as alive.
    """
    try:
        info = json.loads(lock_file.read_bytes().decode("utf-8"))
        pid, host = int(info["pid"]), str(info["host"])
    except (OSError, ValueError, KeyError, TypeError):
        return False
    if host != socket.gethostname():
        return True
    if pid == os.getpid() or pid <= 0:
        return False
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True  # exists, owned by someone else
    return True


def _holder_record() -> bytes:
    info = {
        "pid": os.getpid(),
        "host": socket.gethostname(),
        "started": _dt.datetime.now().astimezone().isoformat(timespec="seconds"),
        "command": " ".join(
            [Path(sys.argv[0]).name, *sys.argv[1:3]] if sys.argv else ["python"]
        ),
    }
    return (json.dumps(info) + "\n").encode("utf-8")


class FolderLock:
    """Exclusive lock of an output folder, as a context manager.

    Parameters
    ----------
    folder : path
        An existing folder; the lock file ``.amrst-lock`` is made in it.
    timeout_s : float
        How long to wait for another writer; 0 fails at once.
    """

    def __init__(
        self, folder: str | os.PathLike[str], timeout_s: float = DEFAULT_TIMEOUT_S
    ) -> None:
        self.folder = Path(folder)
        self.timeout_s = timeout_s
        self._fds: list[int] = []

    @property
    def path(self) -> Path:
        """The lock file."""
        return self.folder / LOCK_NAME

    def __enter__(self) -> FolderLock:
        self.acquire()
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self.release()

    def acquire(self) -> None:
        """Take the lock, waiting up to ``timeout_s``.

        Raises
        ------
        FolderBusy
            Another writer held it for the whole time; the message names it.
        InvalidInput
            The lock file cannot be made (the folder is not writable).
        """
        deadline = time.monotonic() + self.timeout_s
        warned = False
        while True:
            fd = self._open(self.path)
            if fcntl is None:  # pragma: no cover - Windows
                self._fds.append(fd)
                return
            try:
                fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
            except OSError as exc:
                if not isinstance(exc, BlockingIOError):
                    # A file system without locks (some network mounts): write
                    # unguarded rather than not at all.
                    logger.debug("No lock on %s: %s", self.path, exc)
                    self._fds.append(fd)
                    return
                raw = _read_all(fd)
                os.close(fd)
                if time.monotonic() >= deadline:
                    waited = f"; waited {self.timeout_s:g} s" if self.timeout_s else ""
                    raise FolderBusy(
                        f"The folder {self.folder} is being written by another AMRST "
                        f"run ({holder_text(raw)}){waited}. Let it finish (or stop "
                        "it), or choose another output folder."
                    ) from None
                if not warned:
                    logger.warning(
                        "Waiting for another AMRST run writing %s (%s).",
                        self.folder,
                        holder_text(raw),
                    )
                    warned = True
                time.sleep(0.1)
                continue
            if self._names(fd, self.path):
                _write_holder(fd)
                self._fds.append(fd)
                return
            os.close(fd)  # the file was replaced or removed meanwhile: lock anew

    def adopt(self, path: Path) -> None:
        """Also lock the lock file of a folder about to replace this one."""
        fd = self._open(path)
        if fcntl is not None:
            with contextlib.suppress(OSError):  # new: nobody else has it
                fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        _write_holder(fd)
        self._fds.append(fd)

    def release(self) -> None:
        """Remove the lock file if it is ours, then let go (idempotent)."""
        with contextlib.suppress(OSError):
            if any(self._names(fd, self.path) for fd in self._fds):
                self.path.unlink()
        for fd in self._fds:
            with contextlib.suppress(OSError):
                os.close(fd)
        self._fds = []

    def _open(self, path: Path) -> int:
        flags = os.O_RDWR | os.O_CREAT | getattr(os, "O_CLOEXEC", 0)
        flags |= getattr(os, "O_NOFOLLOW", 0)
        try:
            return os.open(path, flags, 0o644)
        except OSError as exc:
            raise InvalidInput(
                f"Cannot write in the output folder {self.folder}: "
                f"{exc.strerror or exc}. Check its permissions or choose another "
                "folder."
            ) from exc

    @staticmethod
    def _names(fd: int, path: Path) -> bool:
        """Tell whether ``path`` still names the file open as ``fd``."""
        try:
            st, now = os.fstat(fd), os.stat(path, follow_symlinks=False)
        except OSError:
            return False
        return (st.st_dev, st.st_ino) == (now.st_dev, now.st_ino)


def _read_all(fd: int) -> bytes:
    with contextlib.suppress(OSError):
        return os.pread(fd, 4096, 0)
    return b""


def _write_holder(fd: int) -> None:
    record = _holder_record()
    with contextlib.suppress(OSError):
        os.ftruncate(fd, 0)
        os.pwrite(fd, record, 0)
