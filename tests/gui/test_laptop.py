"""The window fits a laptop screen: 1366x768, Matches shows 7 rows and why."""

from __future__ import annotations


def test_fits_1366x768_and_matches_shows_seven_rows_and_why(
    loaded_window, qtbot, finish
):
    win = loaded_window
    hint = win.minimumSizeHint()
    assert hint.width() <= 1366
    assert hint.height() <= 768
    win.resize(1366, 768)
    win._default_sizes()
    s = win.session
    finish(s, win.actions.match.trigger, "matches_changed")
    table = win.matches_panel.table
    box = win.matches_panel.explanation_box  # the selected row's explanation
    qtbot.waitUntil(lambda: box.isVisible() and box.height() >= 2 * 18, timeout=3_000)
    qtbot.waitUntil(lambda: table.viewport().height() >= 7 * 22, timeout=3_000)
    assert table.rowAt(6 * 22 + 5) == 6  # the 7th row is on screen
    # Accept coarse and Fine leave the overlay tab on screen.
    win.tabs.setCurrentIndex(0)
    finish(s, win.actions.accept_coarse.trigger, "coarse_accepted")
    # On the next turn of the event loop (its first frame is a stall of its own).
    qtbot.waitUntil(lambda: win.tabs.currentWidget() is win.registration)
    # Distance colouring and its histogram; the stem slices with centre offsets.
    win.registration.colour.setCurrentIndex(1)
    assert win.registration.histogram.isVisible()
    assert "median" in win.registration.histogram.summary()
    win.tabs.setCurrentWidget(win.slices)
    offsets = win.slices.view.offsets_mm()
    assert len(offsets) == 3
    assert any(o < 50 for o in offsets if o == o)


def test_big_scans_are_sliced_in_a_worker(loaded_window, qtbot, finish, monkeypatch):
    """Above SYNC_POINTS the Stem slices tab slices in a display job, off the GUI
    thread, and shows the same slices as the GUI thread would when done."""
    from amrst_gui.views import quality_views

    win = loaded_window
    s = win.session
    finish(s, win.actions.match.trigger, "matches_changed")
    finish(s, win.actions.accept_coarse.trigger, "coarse_accepted")
    win.tabs.setCurrentWidget(win.slices)
    at_once = win.slices.view.offsets_mm()
    monkeypatch.setattr(quality_views, "SYNC_POINTS", 0)  # every scan counts as big
    win.slices.view.set_slices([], "cleared")
    win.slices.refresh()
    assert win.slices._job is not None  # the GUI thread did not slice
    qtbot.waitUntil(lambda: win.slices._job is None, timeout=20_000)
    assert win.slices.view.offsets_mm() == at_once


def test_every_control_of_the_view_rows_is_in_sight_at_1366x768(
    loaded_window, qtbot, finish
):
    """The rows over the views wrap instead of scrolling: at 1366x768 the overlay's
    Top / Front / Side buttons were behind a scroll bar."""
    from PySide6.QtWidgets import QWidget

    win = loaded_window
    finish(win.session, win.actions.run_all.trigger, "fine_finished")
    checked = 0
    for w, h in ((1366, 768), (1920, 1050)):
        win.resize(w, h)
        win._default_sizes()
        for tab in range(win.tabs.count()):
            win.tabs.setCurrentIndex(tab)
            qtbot.wait(150)
            for row in win.tabs.currentWidget().findChildren(QWidget, "control_row"):
                if not row.isVisible():
                    continue
                parent = row.parentWidget()
                assert parent.rect().contains(row.geometry()), (w, tab)
                for control in row.findChildren(QWidget):
                    if control.isVisible() and control.parentWidget() is row:
                        assert row.rect().contains(control.geometry()), (
                            w,
                            tab,
                            control.objectName() or type(control).__name__,
                        )
                        checked += 1
    assert checked >= 20


def test_picking_gives_the_manual_dock_room_and_hands_it_back(
    loaded_window, qtbot, finish
):
    """At 1366x768 the pair table and the rotation locks under it are in sight while
    picking, without scrolling, and the squeezed Matches dock still shows four rows
    with nothing drawn over them; after picking, it gets its room back."""
    win = loaded_window
    win.resize(1366, 768)
    win._default_sizes()
    finish(win.session, win.actions.match.trigger, "matches_changed")
    win.docks["manual"].raise_()
    panel = win.manual_panel
    qtbot.waitUntil(lambda: panel.isVisible())
    before = win.docks["manual"].height()
    panel.set_picking(True)
    qtbot.waitUntil(lambda: win.docks["manual"].height() > before + 50, timeout=3_000)
    viewport = panel.viewport()
    corner = panel.levelled.mapTo(viewport, panel.levelled.rect().bottomLeft())
    assert 0 <= corner.y() <= viewport.height()  # the locks are on screen
    matches = win.matches_panel
    table, button = matches.table, matches.reject_button
    assert table.viewport().height() >= 4 * 22
    below_table = table.mapTo(matches, table.rect().bottomLeft()).y()
    assert button.mapTo(matches, button.rect().topLeft()).y() >= below_table
    text = matches.explanation.parentWidget().parentWidget()  # its scroll area
    below_button = button.mapTo(matches, button.rect().bottomLeft()).y()
    assert text.mapTo(matches, text.rect().topLeft()).y() >= below_button
    panel.set_picking(False)
    qtbot.waitUntil(lambda: abs(win.docks["manual"].height() - before) <= 20)
