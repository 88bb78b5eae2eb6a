"""The engine process of the app: ``python -m amrst_gui.engine_host`` (no Qt).

Runs the steps' worker functions (``amrst_gui.jobs``) for ``engine_process``:
reads one call at a time on stdin (``wire`` frames, see ``serve``), sends
``("progress", fraction, message)`` and ``("log", logger, level, text)`` frames
while it runs and then ``("result", value)`` or ``("error", exception, traceback
text)`` on the stream it was given as stdout. Python's own stdout goes to stderr here, so that
nothing a library prints can break a frame. Cancel is the app killing this
process; it never waits for a check point. ``wire``'s array cache is only used
under the writer's lock and by the reading loop between calls.
"""

from __future__ import annotations

import contextlib
import importlib
import logging
import os
import pickle
import sys
import threading
import traceback
from typing import IO, Any

# Niceness of the engine process: the window's own process goes first for the
# cores, so it stays responsive while a step computes.
NICE = 5

# What the steps import; imported when the process starts, while the user looks
# at the scans, so that the first step does not wait for them.
STEP_MODULES = ("amrst.io.describe", "amrst.pipeline", "amrst.review.quality")


class _PipeReporter:
    """Progress to the app as frames; cancelling is the app killing the process."""

    def __init__(self, send) -> None:
        self._send = send

    def progress(self, fraction: float, message: str = "") -> None:
        self._send(("progress", float(fraction), str(message)))

    def check_cancelled(self) -> None:
        """Never raises: a cancelled call is killed with its process."""


def _portable(exc: BaseException) -> BaseException:
    """``exc`` if it survives pickling, else an AmrstError or RuntimeError that
    says the same (the app tells engine errors from bugs by their class)."""
    from amrst.errors import AmrstError

    try:
        pickle.loads(pickle.dumps(exc))
        return exc
    except Exception:
        kind = AmrstError if isinstance(exc, AmrstError) else RuntimeError
        return kind(f"{exc}" if kind is AmrstError else f"{type(exc).__name__}: {exc}")


class _LogFrames(logging.Handler):
    """The engine's log records, and Python warnings, to the app as frames: the
    app's Log panel shows them as it did when the steps ran in its threads."""

    def __init__(self, send) -> None:
        super().__init__(logging.INFO)
        self._send = send
        self._inside = threading.local()

    def emit(self, record: logging.LogRecord) -> None:
        if getattr(self._inside, "on", False):
            return  # a record logged while a frame is written: not re-entered
        self._inside.on = True
        try:
            self._send(("log", record.name, record.levelno, record.getMessage()))
        except Exception:
            self.handleError(record)
        finally:
            self._inside.on = False


def serve(inp: IO[bytes], out: IO[bytes]) -> None:
    """Answer calls from ``inp`` on ``out`` until ``inp`` closes.

    Frames in: ``("keep", tokens)`` (drop every array the app no longer holds)
    and ``("call", fn, args, kwargs)``. A frame that cannot be read whole is
    fatal: the stream and the arrays' tokens can no longer be trusted, so the
    answer says so and the process ends (the app starts a fresh one).
    """
    from amrst_gui import wire

    cache = wire.ArrayCache(weak=False, first_token=1)
    lock = threading.Lock()

    def send(message: Any) -> None:
        with lock:
            wire.write_message(out, message, cache)

    handler = _LogFrames(send)
    for name in ("amrst", "amrst_gui", "py.warnings"):
        logger = logging.getLogger(name)
        logger.addHandler(handler)
        logger.setLevel(logging.INFO)
    logging.captureWarnings(True)
    reporter = _PipeReporter(send)
    while True:
        seen: set[int] = set()
        try:
            message = wire.read_message(inp, cache, seen)
        except EOFError:
            return
        except BaseException as exc:
            send(("fatal", _portable(exc), traceback.format_exc()))
            return
        if message[0] == "keep":
            cache.keep_only(set(message[1]))
            continue
        _kind, fn, args, kwargs = message
        value = None
        try:
            value = fn(*args, reporter, **kwargs)
            send(("result", value))
        except BaseException as exc:  # every failure goes back to the app
            send(("error", _portable(exc), traceback.format_exc()))
        del message, args, kwargs, fn, value


def main() -> None:
    with contextlib.suppress(OSError, AttributeError):  # not POSIX: as it is
        os.setpriority(
            os.PRIO_PROCESS, 0, max(NICE, os.getpriority(os.PRIO_PROCESS, 0))
        )
    # The frames get the real stdout; print() and C libraries get stderr.
    out = os.fdopen(os.dup(1), "wb")
    os.dup2(2, 1)
    sys.stdout = sys.stderr
    inp = os.fdopen(os.dup(0), "rb")
    for name in STEP_MODULES:
        importlib.import_module(name)
    serve(inp, out)


if __name__ == "__main__":
    main()
