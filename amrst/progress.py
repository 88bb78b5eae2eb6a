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
