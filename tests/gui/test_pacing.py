"""The one queue of the app's own draws: order, replacement, deleted owners, errors."""

from __future__ import annotations

from PySide6.QtCore import QObject

from amrst_gui.pacing import DrawQueue


def test_draws_run_in_turn_and_a_newer_one_takes_the_older_ones_place(qtbot) -> None:
    turns, ran = DrawQueue(), []
    a, b = QObject(), QObject()
    turns.later(a, "scene", lambda: ran.append("a old"))
    turns.later(b, "scene", lambda: ran.append("b"))
    turns.later(a, "scene", lambda: ran.append("a new"))  # same owner and what
    turns.later(a, "adapt", lambda: ran.append("a adapt"))
    assert turns.waits(a, "scene")
    assert not turns.idle
    qtbot.waitUntil(lambda: len(ran) == 3, timeout=2000)
    assert ran == ["a new", "b", "a adapt"]
    qtbot.waitUntil(lambda: turns.idle, timeout=2000)


def test_a_deleted_owner_s_draw_is_skipped_and_a_dropped_one_never_runs(qtbot) -> None:
    turns, ran = DrawQueue(), []
    gone, kept, dropped = QObject(), QObject(), QObject()
    turns.later(gone, "scene", lambda: ran.append("gone"))
    turns.later(dropped, "scene", lambda: ran.append("dropped"))
    turns.later(kept, "scene", lambda: ran.append("kept"))
    turns.drop(dropped, "scene")
    import shiboken6

    shiboken6.delete(gone)  # the C++ object goes, as a closed view's does
    qtbot.waitUntil(lambda: turns.idle, timeout=2000)
    assert ran == ["kept"]


def test_a_draw_that_raises_does_not_hold_up_the_next(qtbot) -> None:
    turns, ran = DrawQueue(), []
    a, b = QObject(), QObject()

    def fails() -> None:
        raise RuntimeError("a view that could not draw")

    turns.later(a, "scene", fails)
    turns.later(b, "scene", lambda: ran.append("b"))
    with qtbot.captureExceptions() as caught:  # the slot's error, reported
        qtbot.waitUntil(lambda: bool(ran), timeout=2000)
    assert ran == ["b"]
    assert [type(exc) for _, exc, _ in caught] == [RuntimeError]
