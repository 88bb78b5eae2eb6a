"""Adaptive level of detail: how many points a view can draw in one frame.

A frame of a point view costs about a fixed time per point, which depends on the
machine (software OpenGL far more than a GPU). A frame on the GUI thread longer than 100 ms is a
stall, so the views measure every frame they render (:class:`FrameCost`, one
for the process: every view runs on the same machine) and draw, at rest, the
largest level of their ladder (:func:`ladder`: the displayed points, then halves)
whose predicted frame fits ``REST_BUDGET_S``; while the camera moves, the largest
up to ``scene.MOVING_POINTS`` that fits ``MOVING_BUDGET_S``.

A new scene starts at ``START_POINTS`` at most and goes up one level (twice the
points) per frame, each time only if twice the last frame still fits the budget,
so no step can overshoot it by much.
No Qt, no VTK here.
"""

from __future__ import annotations

from collections import deque

# Longest frame wanted at rest / while the camera moves (s). Well under the 100 ms
# a user feels as a stall, since the machine may get busier between two frames.
REST_BUDGET_S = 0.045
MOVING_BUDGET_S = 0.03
# Points of the first frame before any frame was measured, and the smallest level.
START_POINTS = 25_000
MIN_LEVEL_POINTS = 10_000
# Frames with fewer points than this say little about the cost per point (the
# fixed cost of a frame dominates); they are not recorded.
MIN_SAMPLE_POINTS = 5_000


def ladder(total: int, smallest: int = MIN_LEVEL_POINTS) -> tuple[int, ...]:
    """The level sizes of a view showing ``total`` points: all, then halves down
    to ``smallest`` (the last level is the first under twice ``smallest``)."""
    levels = [max(int(total), 0)]
    while levels[-1] >= 2 * smallest:
        levels.append(levels[-1] // 2)
    return tuple(levels)


class FrameCost:
    """What a frame of N points costs, from the frames rendered so far.

    A frame is a fixed part (clearing and showing the window, the other actors)
    plus a part per point; the fixed part is assumed to be ``FIXED_SHARE`` of a
    measured frame: a model of points alone would read one busy frame as a slow
    machine and keep the level down for good. The prediction is the most
    pessimistic of the recent frames': a slow frame counts at once, and is
    forgotten only after ``window`` newer ones.
    """

    FIXED_SHARE = 0.25

    def __init__(self, window: int = 4) -> None:
        self._recent: deque[tuple[int, float]] = deque(maxlen=window)

    @property
    def known(self) -> bool:
        """True once a frame was measured."""
        return bool(self._recent)

    def record(self, n_points: int, seconds: float) -> None:
        """A frame of ``n_points`` took ``seconds``."""
        if n_points >= MIN_SAMPLE_POINTS and seconds > 0:
            self._recent.append((n_points, seconds))

    def reset(self) -> None:
        self._recent.clear()

    def predict(self, n_points: int) -> float | None:
        """Seconds a frame of ``n_points`` should take, None before any frame."""
        f = self.FIXED_SHARE
        return max(
            (t * (f + (1 - f) * n_points / n) for n, t in self._recent), default=None
        )


COST = FrameCost()


def pick(
    levels: tuple[int, ...],
    budget_s: float,
    drawn: int | None,
    cap: int | None = None,
    cost: FrameCost = COST,
) -> int:
    """Index into ``levels`` (most points first) of the level to draw next.

    ``drawn`` is what the view draws now (None: nothing yet). The largest level
    whose predicted frame fits ``budget_s``, no larger than ``cap`` nor twice
    ``drawn`` (each frame up tests the next); a first frame (``drawn`` None)
    draws ``START_POINTS`` at most.
    """
    if not levels:
        return 0
    limit = cap if cap is not None else levels[0]
    if drawn is not None:
        limit = min(limit, 2 * max(drawn, 1))
    else:
        # A view's first frame of a scene also uploads its point sets, caption and
        # camera: start small even when frames were measured.
        limit = min(limit, START_POINTS)
    for i, n in enumerate(levels):
        if n > limit and i < len(levels) - 1:
            continue
        t = cost.predict(n)
        if t is None or t <= budget_s or i == len(levels) - 1:
            return i
    return len(levels) - 1
