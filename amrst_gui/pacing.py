"""The draws the app starts itself, one per turn of the event loop. No widgets.

A view's new scene, its next level of detail and the overlay shown after a step are
each a render (a fraction of a second with software OpenGL). Started back to back
they would hold input and repaints for their sum, so they wait in one queue and each
runs ``DRAW_GAP_MS`` after the last frame of any view ended: a zero-delay timer
would run before timers already due.
"""

from __future__ import annotations

import time
from typing import TYPE_CHECKING

import shiboken6
from PySide6.QtCore import QTimer

if TYPE_CHECKING:
    from collections.abc import Callable

    from PySide6.QtCore import QObject

# Milliseconds between the end of a view's frame and the next draw the app starts.
DRAW_GAP_MS = 15


class DrawQueue:
    """The queue of the app's own draws; views ``mark`` the end of each frame."""

    def __init__(self) -> None:
        self._end = -1.0
        self._queue: dict[tuple[int, str], tuple[QObject, Callable[[], None]]] = {}
        self._timer: QTimer | None = None

    def mark(self) -> None:
        """A frame ended now."""
        self._end = time.perf_counter()

    def wait_ms(self) -> int:
        """Milliseconds until the next draw may start (0: now)."""
        left = self._end + DRAW_GAP_MS / 1000 - time.perf_counter()
        return max(0, int(left * 1000) + 1) if left > 0 else 0

    @property
    def idle(self) -> bool:
        """True when no draw waits and the last frame ended a gap ago."""
        return not self._queue and not self.wait_ms()

    def later(self, owner: QObject, what: str, draw: Callable[[], None]) -> None:
        """Run ``draw`` in its turn, unless ``owner`` is deleted first; a newer
        ``draw`` for the same owner and ``what`` takes the older one's place."""
        self._queue[id(owner), what] = (owner, draw)
        if self._timer is None:
            self._timer = QTimer()
            self._timer.setSingleShot(True)
            self._timer.timeout.connect(self._next)
        if not self._timer.isActive():
            self._timer.start(DRAW_GAP_MS)

    def drop(self, owner: QObject, what: str) -> None:
        """Forget ``owner``'s waiting ``what``."""
        self._queue.pop((id(owner), what), None)

    def waits(self, owner: QObject, what: str) -> bool:
        """True while ``owner``'s ``what`` waits for its turn."""
        return (id(owner), what) in self._queue

    def _next(self) -> None:
        assert self._timer is not None
        wait = self.wait_ms()
        if wait:
            self._timer.start(wait)
            return
        try:
            if self._queue:
                key = next(iter(self._queue))
                owner, draw = self._queue.pop(key)
                if shiboken6.isValid(owner):
                    draw()
        finally:  # a draw that raised does not hold up the ones after it
            if self._queue:
                self._timer.start(DRAW_GAP_MS)


DRAWS = DrawQueue()
