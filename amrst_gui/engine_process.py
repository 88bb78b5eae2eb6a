"""The engine process: where the app's heavy work runs, so the window never waits.

A step's numpy, scipy and small_gicp calls hold the Python GIL for a long time on
millions of points; in a thread of the app, the GUI thread would wait behind each
of them. A separate process has its own GIL. The app's worker thread only waits
on a pipe; the operating system shares the cores, and the engine process runs
niced so that the window comes first.

``call(fn, *args, reporter=..., **kwargs)`` runs ``fn(*args, reporter,
**kwargs)`` (a function of ``amrst_gui.jobs``: inputs and results are engine
dataclasses and arrays) in the engine process, ``python -m amrst_gui.engine_host``
(plain Python: the engine and numpy, no Qt, not the caller's main script). The
scans cross the pipe once (``wire``: each array names itself by a token after
that). Cancel kills the process: the step stops at once, at any size, keeps
nothing, and a fresh process starts for the next one. Where no process can be
started (a frozen app has no interpreter; Windows pipes cannot be polled), the
function runs in the caller's thread.
"""

from __future__ import annotations

import atexit
import contextlib
import logging
import os
import select
import subprocess
import sys
import threading
import time
from pathlib import Path
from typing import TYPE_CHECKING, Any

from amrst.errors import AmrstError, Cancelled
from amrst.progress import NULL_REPORTER
from amrst_gui import wire

if TYPE_CHECKING:
    from collections.abc import Callable, Iterator

    from amrst.progress import Reporter

log = logging.getLogger("amrst_gui.engine")

POLL_S = 0.05  # how often a waiting worker looks at Cancel
PIPE_BYTES = 1 << 20  # the pipe to the engine process holds 1 MB (Linux)


def _command(module: str) -> tuple[list[str], dict[str, str]]:
    """The command and environment that run ``python -m module`` with this
    checkout of the app importable; RuntimeError in a frozen app."""
    import amrst

    if getattr(sys, "frozen", False):  # sys.executable is the app itself
        raise RuntimeError("no Python interpreter to run the engine process")
    root = str(Path(amrst.__file__).resolve().parents[1])
    path = os.environ.get("PYTHONPATH")
    env = {
        **os.environ,
        "PYTHONPATH": root if not path else os.pathsep.join([root, path]),
    }
    return [sys.executable, "-m", module], env


def _end(proc: subprocess.Popen[bytes] | None) -> None:
    """Kill the process (if it still runs), reap it and close its pipes."""
    if proc is None:
        return
    if proc.poll() is None:
        proc.kill()
    proc.wait()
    for pipe in (proc.stdin, proc.stdout):
        if pipe is not None:
            with contextlib.suppress(OSError):
                pipe.close()


class EngineProcess:
    """The engine process; one call at a time (callers queue on a lock)."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._holder = "another job"  # what the last call was, as a waiting one says
        self._proc: subprocess.Popen[bytes] | None = None
        self._writer: _Writer | None = None
        self._cache = wire.ArrayCache(weak=True, first_token=0)

    @property
    def pid(self) -> int | None:
        """The process id of the running engine process, if one runs."""
        proc = self._proc
        return proc.pid if proc is not None and proc.poll() is None else None

    def start(self) -> None:
        """Start the process now (its imports take a second, in the process).

        Never waits (the GUI thread calls it; while a call runs, the process runs
        too) and never raises: without it, steps run in the caller's thread.
        """
        if not self._lock.acquire(blocking=False):
            return
        try:
            self._ensure()
        except Exception as exc:
            log.info("No engine process (%s); steps run in the app", exc)
        finally:
            self._lock.release()

    def _ensure(self) -> subprocess.Popen[bytes]:
        if self._proc is None or self._proc.poll() is not None:
            self.stop()  # one that died: its pipes and arrays
            if os.name == "nt":  # select() and non-blocking writes need POSIX pipes
                raise RuntimeError("the engine process needs POSIX pipes")
            command, env = _command("amrst_gui.engine_host")
            self._proc = subprocess.Popen(
                command,
                stdin=subprocess.PIPE,
                stdout=subprocess.PIPE,
                bufsize=0,  # reads: select() must see every byte not yet read
                env=env,
            )
            assert self._proc.stdin is not None
            self._writer = _Writer(self._proc.stdin.fileno())
        return self._proc

    def stop(self) -> None:
        """End the process without waiting for what it computes."""
        proc, self._proc, self._writer = self._proc, None, None
        self._cache.clear()  # a new process holds none of the arrays
        _end(proc)

    def call(
        self,
        fn: Callable[..., Any],
        *args: Any,
        reporter: Reporter,
        stoppable: bool = True,
        what: str = "another job",
        **kwargs: Any,
    ) -> Any:
        """``fn(*args, reporter, **kwargs)`` in the engine process; raises what it
        raised, and ``Cancelled`` within ``POLL_S`` of a Cancel. A call that is
        not ``stoppable`` (Export: it writes files) runs to its end whatever
        Cancel says, as it did in the app's thread. ``what`` names the call to one
        that waits for it (the other window's)."""
        watch = reporter if stoppable else NULL_REPORTER
        with self._turn(reporter, what):
            watch.check_cancelled()
            try:
                proc = self._ensure()
            except Exception as exc:
                log.info("No engine process (%s); the step runs in the app", exc)
                return fn(*args, reporter, **kwargs)
            # Held until the answer is read: the process may name any of them.
            held = self._cache.alive()
            writer = self._writer
            assert writer is not None  # made with the process
            try:
                writer.reporter = watch
                # What the app no longer holds goes first, before the new arrays
                # arrive: the process never holds the old scans and the new ones.
                wire.write_message(writer, ("keep", list(held)), self._cache)
                wire.write_message(writer, ("call", fn, args, kwargs), self._cache)
                kind, payload = self._answer(proc, reporter, watch)
            except Cancelled:
                self.stop()  # it would compute on
                # A fresh process imports now, while the user decides what next
                # (a second of imports less for the step that follows).
                with contextlib.suppress(Exception):
                    self._ensure()
                raise
            except (OSError, EOFError) as exc:  # the process is gone
                with contextlib.suppress(subprocess.TimeoutExpired):
                    proc.wait(timeout=1.0)  # its pipe closed as it ended: reap it
                code = proc.poll()
                self.stop()
                watch.check_cancelled()
                raise EngineStopped(
                    f"The engine process stopped ({_ended(code, exc)}) "
                    "before the work was done. Run it again; if it stops again, "
                    "close other programs to free memory."
                ) from exc
            finally:
                del held
            if kind == "result":
                return payload
            if kind == "fatal":  # it could not read the call: start afresh
                self.stop()
            error, text = payload
            with contextlib.suppress(AttributeError, TypeError):
                error.__traceback_text__ = text
            raise error

    @contextlib.contextmanager
    def _turn(self, reporter: Reporter, what: str) -> Iterator[None]:
        """Hold the process for one call; while another holds it, say whose turn it
        is on ``reporter`` and heed its Cancel (a call not stoppable once it runs
        has not started yet)."""
        if not self._lock.acquire(blocking=False):
            reporter.progress(0.0, f"Waiting for {self._holder} to end…")
            while not self._lock.acquire(timeout=POLL_S):
                reporter.check_cancelled()
        self._holder = what
        try:
            yield
        finally:
            self._lock.release()

    def serving(self, what: str) -> bool:
        """Tell whether the call named ``what`` holds the process now."""
        return self._lock.locked() and self._holder == what

    def trim(self) -> None:
        """Tell an idle engine process which arrays the app still holds, so it
        lets go of the others now (a new pair was opened); never waits."""
        if not self._lock.acquire(blocking=False):
            return  # a call runs: it says so itself
        try:
            if (
                self._writer is None
                or self._proc is None
                or self._proc.poll() is not None
            ):
                return
            self._writer.reporter = NULL_REPORTER
            wire.write_message(
                self._writer, ("keep", list(self._cache.alive())), self._cache
            )
        except OSError:
            self.stop()
        finally:
            self._lock.release()

    def _answer(
        self, proc: subprocess.Popen[bytes], reporter: Reporter, watch: Reporter
    ) -> tuple[str, Any]:
        """Relay progress and logs until the answer: ``("result", value)``, or
        ``("error" | "fatal", (exception, traceback text))``."""
        assert proc.stdout is not None
        while True:
            while not select.select([proc.stdout], [], [], POLL_S)[0]:
                watch.check_cancelled()
            message = wire.read_message(proc.stdout, self._cache)
            kind = message[0]
            if kind == "progress":
                reporter.progress(message[1], message[2])
                watch.check_cancelled()
            elif kind == "log":
                _, name, level, text = message
                logging.getLogger(name).log(level, "%s", text)
            elif kind == "result":
                return kind, message[1]
            else:
                return kind, (message[1], message[2])


class EngineStopped(AmrstError):
    """The engine process ended during a call (killed, out of memory)."""


def _ended(code: int | None, exc: BaseException) -> str:
    """How the engine process ended, for a message."""
    if code is None:
        return str(exc) or type(exc).__name__
    return f"killed by signal {-code}" if code < 0 else f"exit code {code}"


class _Writer:
    """Writes to the engine's stdin that look at Cancel while the pipe is full
    (the process reads only once its imports are done, and a big scan's arrays
    take long to pass through the pipe)."""

    def __init__(self, fd: int) -> None:
        self._fd = fd
        os.set_blocking(fd, False)
        with contextlib.suppress(OSError, AttributeError):  # Linux: fewer turns
            import fcntl

            fcntl.fcntl(fd, fcntl.F_SETPIPE_SZ, PIPE_BYTES)
        self.reporter: Reporter | None = None

    def write(self, data) -> int:
        view = memoryview(data).cast("B")
        done = 0
        while done < len(view):
            if not select.select([], [self._fd], [], POLL_S)[1]:
                if self.reporter is not None:
                    self.reporter.check_cancelled()
                continue
            try:
                done += os.write(self._fd, view[done:])
            except BlockingIOError:
                continue
        return done

    def flush(self) -> None:
        """Nothing: every write went to the pipe."""


ENGINE = EngineProcess()
atexit.register(ENGINE.stop)


def in_engine(
    fn: Callable[..., Any], stoppable: bool = True, what: str = "another job"
) -> Callable[..., Any]:
    """``fn`` (called as ``fn(*args, reporter, **kwargs)``) run in the engine
    process: the form ``workers.run_stage`` calls. ``what`` names it to a job that
    waits for it."""

    def run(*args: Any, **kwargs: Any) -> Any:
        *inputs, reporter = args
        start = time.perf_counter()
        out = ENGINE.call(
            fn, *inputs, reporter=reporter, stoppable=stoppable, what=what, **kwargs
        )
        log.debug("%s in the engine process: %.2f s", fn, time.perf_counter() - start)
        return out

    return run
