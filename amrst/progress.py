"""Progress and cancel: stages report through a Reporter and check for cancel between steps.

The GUI passes a reporter that forwards progress to a queued signal and holds the
cancel request in a ``threading.Event``; the CLI passes a terminal one; tests pass
``NULL_REPORTER``. The check points live here, in ``amrst``, so every front end runs
the same code.
"""

from __future__ import annotations

import threading
from typing import TYPE_CHECKING, Protocol

from amrst.errors import Cancelled

if TYPE_CHECKING:
    from collections.abc import Callable


class Reporter(Protocol):
    """What a stage may call while it runs."""

    def progress(self, fraction: float, message: str = "") -> None:
        """Report ``fraction`` in [0, 1] of the current stage done, with a short message."""

    def check_cancelled(self) -> None:
        """Raise :class:`amrst.errors.Cancelled` if the user asked to stop."""


class NullReporter:
    """Ignores progress and never cancels."""

    def progress(self, fraction: float, message: str = "") -> None:
        """Ignore the progress."""

    def check_cancelled(self) -> None:
        """Never cancel."""


NULL_REPORTER = NullReporter()


class EventReporter:
    """A reporter whose cancel request is a ``threading.Event``; progress goes to a callback.

    Parameters
    ----------
    on_progress : callable or None
        Called as ``on_progress(fraction, message)``; may be called from a worker thread.
    """

    def __init__(
        self, on_progress: Callable[[float, str], object] | None = None
    ) -> None:
        self._cancel = threading.Event()
        self._on_progress = on_progress

    def cancel(self) -> None:
        """Ask the running stage to stop at its next check point."""
        self._cancel.set()

    @property
    def cancelled(self) -> bool:
        """True once :meth:`cancel` was called."""
        return self._cancel.is_set()

    def progress(self, fraction: float, message: str = "") -> None:
        """Pass ``fraction``, clipped to [0, 1], and ``message`` to the callback."""
        if self._on_progress is not None:
            self._on_progress(min(max(float(fraction), 0.0), 1.0), message)

    def check_cancelled(self) -> None:
        """Raise :class:`amrst.errors.Cancelled` once :meth:`cancel` was called."""
        if self._cancel.is_set():
            raise Cancelled()


class SubReporter:
    """Maps a sub-stage's [0, 1] onto the range [start, stop] of a parent reporter."""

    def __init__(
        self, parent: Reporter, start: float, stop: float, label: str = ""
    ) -> None:
        self._parent = parent
        self._start = start
        self._span = stop - start
        self._label = label

    def progress(self, fraction: float, message: str = "") -> None:
        """Report ``fraction`` of the sub-stage as its share of [start, stop]."""
        # A message that already names the stage is not prefixed twice.
        text = (
            f"{self._label}: {message}"
            if self._label and message and not message.startswith(self._label)
            else (message or self._label)
        )
        self._parent.progress(
            self._start + self._span * min(max(fraction, 0.0), 1.0), text
        )

    def check_cancelled(self) -> None:
        """Ask the parent reporter."""
        self._parent.check_cancelled()


class SharedReporter:
    """Lets ``n`` tasks running at once report to one parent.

    Each task's [0, 1] counts 1/n of [start, stop], so the parent sees a monotonic sum
    while every task's own progress is monotonic. Thread-safe; cancel checks go to the
    parent.
    """

    def __init__(
        self, parent: Reporter, n: int, start: float = 0.0, stop: float = 1.0
    ) -> None:
        import threading

        self._parent, self._start, self._span = parent, start, stop - start
        self._done = [0.0] * n
        self._lock = threading.Lock()
        self._stop = threading.Event()

    def stop(self) -> None:
        """Make every task's next cancel check raise Cancelled (a sibling failed)."""
        self._stop.set()

    def task(self, i: int, label: str = "") -> Reporter:
        """Return the reporter task ``i`` reports to."""
        return _SharedTask(self, i, label)

    def _report(self, i: int, fraction: float, message: str) -> None:
        with self._lock:
            self._done[i] = max(self._done[i], min(max(fraction, 0.0), 1.0))
            total = sum(self._done) / len(self._done)
            self._parent.progress(self._start + self._span * total, message)

    def check_cancelled(self) -> None:
        """Raise Cancelled after :meth:`stop`, else ask the parent reporter."""
        if self._stop.is_set():
            raise Cancelled()
        self._parent.check_cancelled()


class _SharedTask:
    def __init__(self, shared: SharedReporter, i: int, label: str) -> None:
        self._shared, self._i, self._label = shared, i, label

    def progress(self, fraction: float, message: str = "") -> None:
        text = f"{self._label}: {message}" if self._label and message else message
        self._shared._report(self._i, fraction, text or self._label)

    def check_cancelled(self) -> None:
        self._shared.check_cancelled()
