"""Pacing the GUI thread's own work (issue 15): lanes for background jobs and
the gap after a frame.

``LANES``: background jobs that run one at a time (the views' scenes; the Scans
dock's descriptions, which also wait for the views). ``PACE``: when the app's
next work of its own on the GUI thread may start, ``DRAW_GAP_MS`` after a view's
last frame, so two pieces of work never share one stall. No widgets here.
"""

from __future__ import annotations

import contextlib
import os
import threading
import time
from typing import TYPE_CHECKING, ClassVar

if TYPE_CHECKING:
    from amrst.progress import EventReporter


# Background work that runs one job at a time, whatever the pool allows (issue 15).
# Every Python thread computing at once competes with the GUI thread for the GIL,
# and CPython hands the GIL over unfairly: with a step, three views' scenes and two
# scans' descriptions running together the GUI thread waited 0.2-0.5 s for it (a
# 10M-point load), and one busy worker doubles the time of a frame. The views'
# scenes (and stem slices) take turns in the "display" lane; the Scans dock's
# descriptions in the "describe" lane, which also waits while a scene is being
# built or waits to be: the views come first, a tooltip can wait.
class _Lanes:
    """One running job per lane; "describe" yields to "display", and waits until
    the views have not drawn for ``QUIET_S`` (``MAX_DEFER_S`` at most): a view
    steps its level of detail up for a few frames after a new scene."""

    AFTER: ClassVar[dict[str, tuple[str, ...]]] = {"describe": ("display",)}
    QUIET: ClassVar[tuple[str, ...]] = ("describe",)
    QUIET_S = 0.3
    MAX_DEFER_S = 5.0

    def __init__(self) -> None:
        self._cond = threading.Condition()
        self._running: dict[str, int] = {}
        self._waiting: dict[str, int] = {}
        self._last_draw = -1e9

    NAMES: ClassVar[tuple[str, ...]] = ("display", "describe")

    def __contains__(self, lane: object) -> bool:
        return lane in self.NAMES

    def drew(self) -> None:
        """A view drew a frame now, or has a scene to draw (GUI thread)."""
        self._last_draw = time.perf_counter()

    def idle(self, lane: str) -> bool:
        """True if no job of ``lane`` runs or waits."""
        return not (self._running.get(lane, 0) or self._waiting.get(lane, 0))

    def _must_wait(self, lane: str, since: float) -> bool:
        if self._running.get(lane, 0):
            return True
        if not all(self.idle(o) for o in self.AFTER.get(lane, ())):
            return True
        now = time.perf_counter()
        # From its own start too: the views' scenes of the same new scan may not
        # have reached their lane yet.
        return (
            lane in self.QUIET
            and now - max(self._last_draw, since) < self.QUIET_S
            and now - since < self.MAX_DEFER_S
        )

    @contextlib.contextmanager
    def enter(self, lane: str, reporter: EventReporter):
        with self._cond:
            self._waiting[lane] = self._waiting.get(lane, 0) + 1
            since = time.perf_counter()
            try:
                while self._must_wait(lane, since):
                    self._cond.wait(0.05)
                    reporter.check_cancelled()  # dropped while it waited
            finally:
                self._waiting[lane] -= 1
            self._running[lane] = 1
            self._cond.notify_all()
        try:
            yield
        finally:
            with self._cond:
                self._running[lane] = 0
                self._cond.notify_all()


LANES = _Lanes()


# Milliseconds between two draws the app starts itself (the next view's scene, the
# next level of detail): a zero-delay timer ran before timers already due, so two
# renders could follow each other with nothing in between (input, repaints) and
# the window stalled for their sum (issue 15).
DRAW_GAP_MS = 15


class Pace:
    """When the app's next work of its own on the GUI thread may start (a draw, a
    job's result): ``DRAW_GAP_MS`` after the last frame of any view ended
    (``mark``). Timers and queued results due together ran back to back, so one
    view's next level of detail followed another view's new scene, or a step's
    result was applied right after a frame, with no turn of the event loop
    between them."""

    def __init__(self) -> None:
        self._end = -1.0

    def mark(self) -> None:
        """A frame ended now."""
        self._end = time.perf_counter()
        LANES.drew()

    def wait_ms(self) -> int:
        """Milliseconds until the next draw may start (0: now)."""
        left = self._end + DRAW_GAP_MS / 1000 - time.perf_counter()
        return max(0, int(left * 1000) + 1) if left > 0 else 0


PACE = Pace()


# Niceness of all background work (Linux, per thread; POSIX processes): the app's
# worker threads, the engine process and the Scans dock's helper process, so the
# window's own thread goes first for the cores.
BACKGROUND_NICE = 5


def at_least_nice(nice: int = BACKGROUND_NICE) -> None:
    """Run the calling thread (Linux: each thread has its own; threads started
    after inherit it) at niceness ``nice``, or above if it already is: a process
    started from a niced worker thread inherits that thread's niceness, and a
    relative ``os.nice`` there made the engine and helper processes nice 10."""
    with contextlib.suppress(OSError, AttributeError):  # not POSIX: no-op
        if os.getpriority(os.PRIO_PROCESS, 0) < nice:
            os.setpriority(os.PRIO_PROCESS, 0, nice)
