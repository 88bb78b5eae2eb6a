"""When the app's next draw of its own may start on the GUI thread. No widgets.

Two renders the app starts itself (the next view's scene, the next level of
detail) never follow each other in one turn of the event loop: a zero-delay timer
runs before timers already due, so input and repaints would wait for their sum.
"""

from __future__ import annotations

import time

# Milliseconds between the end of a view's frame and the next draw the app starts.
DRAW_GAP_MS = 15


class Pace:
    """``DRAW_GAP_MS`` after the last frame of any view ended (``mark``)."""

    def __init__(self) -> None:
        self._end = -1.0

    def mark(self) -> None:
        """A frame ended now."""
        self._end = time.perf_counter()

    def wait_ms(self) -> int:
        """Milliseconds until the next draw may start (0: now)."""
        left = self._end + DRAW_GAP_MS / 1000 - time.perf_counter()
        return max(0, int(left * 1000) + 1) if left > 0 else 0


PACE = Pace()
