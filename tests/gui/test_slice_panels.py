"""Stem slices: new heights replace the panels, never draw over the old ones."""

from __future__ import annotations

from PySide6.QtCore import Qt
from PySide6.QtWidgets import QWidget


def _cells(view) -> list[QWidget]:
    return view.findChildren(
        QWidget, "slice_cell", Qt.FindChildOption.FindDirectChildrenOnly
    )


def _slices_of_the_accepted_match(win, qtbot, finish):
    """Match, accept, then show the Stem slices tab; return its view."""
    s = win.session
    finish(s, win.actions.match.trigger, "matches_changed")
    finish(s, win.actions.accept_coarse.trigger, "coarse_accepted")
    qtbot.waitUntil(lambda: win.tabs.currentWidget() is win.registration)
    win.tabs.setCurrentWidget(win.slices)
    view = win.slices.view
    qtbot.waitUntil(lambda: len(view.slices) == 3)
    return view


def test_new_heights_replace_the_slice_panels(loaded_window, qtbot, finish):
    win = loaded_window
    view = _slices_of_the_accepted_match(win, qtbot, finish)
    edit = win.slices.heights
    for heights in ("0.5, 3, 6, 8", "0.3, 1.3, 3", "1, 2"):
        n = len(heights.split(","))
        edit.setFocus()
        edit.selectAll()
        qtbot.keyClicks(edit, heights)
        qtbot.keyClick(edit, Qt.Key.Key_Return)
        assert len(view.slices) == n
        # At once, before the event loop turns: only the new panels are in the view.
        assert len(_cells(view)) == n
        assert view.row.count() == n
        qtbot.waitUntil(lambda n=n: sum(c.isVisible() for c in _cells(view)) == n)
        rects = [c.geometry() for c in _cells(view)]
        assert not any(a.intersects(b) for i, a in enumerate(rects) for b in rects[:i])
        captions = [t for t, _note in view.captions()]
        assert [c.split(" m ")[0] for c in captions] == [
            f"{float(h):g}" for h in heights.split(",")
        ]


def test_slices_follow_the_selected_candidate(loaded_window, qtbot, finish):
    """Selecting a candidate before accepting it slices both scans under its pose,
    as the After coarse overlay previews it; the accepted one again when selected."""
    win = loaded_window
    s = win.session
    view = _slices_of_the_accepted_match(win, qtbot, finish)
    assert view.caption.startswith("Stem slices after coarse registration")
    accepted = s.accepted_coarse.candidate
    other = next(c for c in s.matches if c.id != accepted.id)
    s.select_match(other.id)
    assert view.caption.startswith(
        f"Stem slices of candidate #{other.rank} (selected, not accepted)"
    )
    s.select_match(accepted.id)
    assert view.caption.startswith("Stem slices after coarse registration")
    qtbot.waitUntil(lambda: sum(c.isVisible() for c in _cells(view)) == 3)
    qtbot.wait(50)  # the replaced panels are deleted on the next turn


def test_slices_show_the_proposed_candidate_before_any_accept(
    loaded_window, qtbot, finish
):
    """Before Accept coarse, the candidate it would take is sliced (a technician
    judging a failed pair had only "No registration to slice yet")."""
    win = loaded_window
    s = win.session
    finish(s, win.actions.match.trigger, "matches_changed")
    assert s.accepted_coarse is None
    s.select_match(s.coarse.candidate.id)
    win.tabs.setCurrentWidget(win.slices)
    view = win.slices.view
    qtbot.waitUntil(lambda: len(view.slices) == 3)
    rank = s.coarse.candidate.rank
    assert view.caption.startswith(
        f"Stem slices of candidate #{rank} (proposed, not accepted)"
    )
    qtbot.wait(50)  # the replaced panels are deleted on the next turn
