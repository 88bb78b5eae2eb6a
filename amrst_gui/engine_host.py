"""The engine process of the app: ``python -m amrst_gui.engine_host`` (no Qt).

Runs the steps' worker functions (``amrst_gui.jobs``) for ``engine_process``:
reads one call at a time on stdin (``wire`` frames: ``("call", fn, args, kwargs,
tokens)``), sends ``("progress", fraction, message)`` frames while it runs and
then ``("result", value)`` or ``("error", exception, traceback text)`` on the
stream it was given as stdout. Python's own stdout goes to stderr here, so that
nothing a library prints can break a frame. Cancel is the app killing this
process; it never waits for a check point.
"""

from __future__ import annotations

import contextlib
import os
import pickle
import sys
import threading
import traceback
from typing import IO, Any

# The window's own process goes first for the cores (AMRST_ENGINE_NICE to change).
NICE = int(os.environ.get("AMRST_ENGINE_NICE", "5") or 0)


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


def serve(inp: IO[bytes], out: IO[bytes]) -> None:
    """Answer calls from ``inp`` on ``out`` until ``inp`` closes."""
    from amrst_gui import wire

    cache = wire.ArrayCache(weak=False, first_token=1)
    lock = threading.Lock()

    def send(message: Any) -> None:
        with lock:
            wire.write_message(out, message, cache)

    reporter = _PipeReporter(send)
    while True:
        seen: set[int] = set()
        try:
            message = wire.read_message(inp, cache, seen)
        except EOFError:
            return
        except Exception as exc:  # read whole, but not understood: say so
            send(("error", _portable(exc), traceback.format_exc()))
            continue
        _kind, fn, args, kwargs, held = message
        # Keep what the app still holds and what this call names; no more.
        cache.keep_only(set(held) | seen)
        value = None
        try:
            value = fn(*args, reporter, **kwargs)
            send(("result", value))
        except BaseException as exc:  # every failure goes back to the app
            send(("error", _portable(exc), traceback.format_exc()))
        del message, args, kwargs, fn, value


def main() -> None:
    with contextlib.suppress(OSError, AttributeError):  # no nice() on Windows
        if NICE:
            os.nice(NICE)
    # The frames get the real stdout; print() and C libraries get stderr.
    out = os.fdopen(os.dup(1), "wb")
    os.dup2(2, 1)
    sys.stdout = sys.stderr
    inp = os.fdopen(os.dup(0), "rb")
    from amrst_gui.warmup import import_worker_modules

    import_worker_modules()
    serve(inp, out)


if __name__ == "__main__":
    main()
