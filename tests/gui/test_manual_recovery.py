"""Manual recovery by eye, through the real window: picked points marked and
numbered in both views, per-pair dX / dY / dZ, a Nudge whose score follows the
turn, pairs saved and loaded as CSV, and the wheel zooming to the cursor."""

from __future__ import annotations

import numpy as np
from _picking import click

from amrst.types import local_transform
from amrst_gui.views.pick_marks import LABELS_ACTOR


def _truth_local(win):
    s = win.session
    return local_transform(s.truth, s.cloud("target"), s.cloud("source"))


def _scan_views(win, qtbot):
    win.tabs.setCurrentIndex(0)  # the Scans tab: target | source
    views = win.scans_area.panes["target"].view, win.scans_area.panes["source"].view
    qtbot.waitUntil(lambda: all(v.isVisible() for v in views))
    return views


def test_picked_points_are_marked_and_numbered_with_dx_dy_dz(loaded_window, qtbot):
    win = loaded_window
    s = win.session
    panel = win.manual_panel
    views = _scan_views(win, qtbot)
    panel.set_picking(True)
    T = _truth_local(win)
    src = s.cloud("source").xyz
    tgt = s.cloud("target").xyz
    picks = [src[i] for i in (0, len(src) // 3, 2 * len(src) // 3)]
    for k, p in enumerate(picks):
        # The target point: the target's point nearest the truly moved source point.
        q = tgt[np.argmin(np.linalg.norm(tgt - (T[:3, :3] @ p + T[:3, 3]), axis=1))]
        click(views[0], q)
        # Shown at once: a marker in the target view and a row with its point.
        assert views[0].marks.pending is not None
        assert panel.table.rowCount() == k + 1
        assert panel.table.item(k, 5).text() == "source?"
        click(views[1], p)
        assert len(panel.pairs) == k + 1
        assert views[0].marks.pending is None
    assert views[0].marks.labels == ["1", "2", "3"]
    assert views[1].marks.labels == ["1", "2", "3"]
    assert "pick_markers" in views[0].plotter.actors
    assert LABELS_ACTOR in views[1].plotter.actors
    np.testing.assert_allclose(
        views[1].marks.points, np.array([p for _t, p in panel.pairs])
    )
    # Per pair: dX, dY, dZ and the distance, in cm, equal to the fit's residuals.
    headers = [panel.table.horizontalHeaderItem(j).text() for j in range(6)]
    assert headers[2:5] == ["dX", "dY", "dZ"]
    fit = panel.fit
    assert fit is not None
    for i in range(3):
        d = [float(panel.table.item(i, j).text()) for j in (2, 3, 4)]
        assert abs(np.linalg.norm(d) - fit.residuals_m[i] * 100) < 0.1
        dist = float(panel.table.item(i, 5).text().split()[0])
        assert abs(dist - fit.residuals_m[i] * 100) < 0.06
    assert "Achievable RMS" in panel.fit_label.text()
    # Deleting a pair drops its marker; Undo brings it back.
    panel.delete_selected()
    assert views[0].marks.labels == ["1", "2"]
    assert len([n for n in views[0].plotter.actors if n.startswith("pick_")]) == 2
    panel.undo()
    assert views[1].marks.labels == ["1", "2", "3"]


def test_nudge_score_changes_with_the_turn_and_the_slider_follows(loaded_window, qtbot):
    win = loaded_window
    s = win.session
    panel = win.manual_panel
    win.docks["manual"].raise_()  # the score is computed where it is seen
    qtbot.waitUntil(panel.isVisible)
    T = _truth_local(win)
    src = s.cloud("source").xyz[[0, len(s.cloud("source")) // 2]]
    for a, b in zip(src @ T[:3, :3].T + T[:3, 3], src, strict=True):
        panel.add_pair(a, b)
    texts, medians = [], []
    for yaw in (-150.0, -90.0, -30.0, 0.0, 30.0, 90.0):
        panel.yaw.setValue(yaw)
        # The slider follows the typed turn.
        assert panel.yaw_slider.value() == round(yaw)
        texts.append(panel.score_label.text())
        medians.append(panel.live_score(panel.nudged_pose())[0])
    # Far from the right pose too, each turn reads differently.
    assert len(set(texts)) == len(texts)
    # The right turn (0°) has the lowest median distance.
    assert int(np.argmin(medians)) == 3
    assert f"{medians[3] * 100:.1f} cm" in texts[3]
    assert "not only where both scans saw the scene" in texts[3]


def test_a_new_pair_resets_the_nudge_and_says_so(loaded_window, qtbot, caplog):
    win = loaded_window
    s = win.session
    panel = win.manual_panel
    T = _truth_local(win)
    src = s.cloud("source").xyz[[0, len(s.cloud("source")) // 2, -1]]
    moved = src @ T[:3, :3].T + T[:3, 3]
    panel.add_pair(moved[0], src[0])
    panel.add_pair(moved[1], src[1])
    panel.yaw.setValue(25.0)
    with caplog.at_level("INFO", logger="amrst_gui.manual"):
        panel.add_pair(moved[2], src[2])
    assert panel.yaw.value() == 0.0
    assert "Nudge back to zero: it now moves the fit of 3 pairs." in caplog.text


def test_pairs_saved_and_loaded_as_csv_and_the_ghost_of_the_other_scan(
    loaded_window, qtbot, tmp_path
):
    from amrst.review.pairs_file import read_pairs

    win = loaded_window
    s = win.session
    panel = win.manual_panel
    views = _scan_views(win, qtbot)
    T = _truth_local(win)
    src = s.cloud("source").xyz[[0, len(s.cloud("source")) // 2, -1]]
    for a, b in zip(src @ T[:3, :3].T + T[:3, 3], src, strict=True):
        panel.add_pair(a, b)
    path = tmp_path / "pairs.csv"
    panel.save_pairs(path)
    _t_world, s_world = read_pairs(path)
    np.testing.assert_allclose(s_world, src + s.cloud("source").offset, atol=1e-6)
    before = [(a.copy(), b.copy()) for a, b in panel.pairs]
    panel.delete_selected()
    panel.load_pairs(path)
    assert len(panel.pairs) == 3
    for (a, b), (c, d) in zip(before, panel.pairs, strict=True):
        np.testing.assert_allclose(a, c, atol=1e-6)
        np.testing.assert_allclose(b, d, atol=1e-6)
    assert views[0].marks.labels == ["1", "2", "3"]
    # Under the pairs' rough pose, each view can show the other scan moved into it.
    panel.ghost.setChecked(True)
    assert views[0].marks.ghost_points > 0
    assert "under the fit of" in panel.ghost.text()  # which pose moves it
    assert "pick_ghost" in views[1].plotter.actors
    panel.ghost.setChecked(False)
    assert "pick_ghost" not in views[0].plotter.actors


def test_a_shift_lock_holds_that_world_shift_at_zero(loaded_window):
    win = loaded_window
    s = win.session
    panel = win.manual_panel
    T = _truth_local(win)
    src = s.cloud("source").xyz[[0, len(s.cloud("source")) // 2, -1]]
    for a, b in zip(src @ T[:3, :3].T + T[:3, 3], src, strict=True):
        panel.add_pair(a, b)
    panel.locks[2].setChecked(True)
    T_world = s.world(panel.fit.T_target_source)
    assert abs(T_world[2, 3]) < 1e-9
    # The locked fit is the best one with no vertical shift: the unlocked fit's
    # turn and horizontal shift, as the levelled fit's height is free of them.
    locked = panel.fit.T_target_source
    panel.locks[2].setChecked(False)
    free = s.world(panel.fit.T_target_source)
    assert abs(free[2, 3]) > 1e-3
    np.testing.assert_allclose(T_world[:3, :3], free[:3, :3], atol=1e-5)
    np.testing.assert_allclose(T_world[:2, 3], free[:2, 3], atol=1e-4)
    assert locked is not panel.fit.T_target_source


def test_a_locked_fit_refuses_pairs_that_leave_the_turn_unknown(loaded_window):
    panel = loaded_window.manual_panel
    panel.levelled.setChecked(True)
    panel.locks[2].setChecked(True)
    p = loaded_window.session.cloud("source").xyz[0]
    panel.add_pair(p, p)
    panel.add_pair(p, p)  # the same point twice: any turn fits it
    assert panel.fit is None
    assert "heading is unknown" in panel.fit_label.text()
    panel.delete_selected()  # the last pair
    q = loaded_window.session.cloud("source").xyz[-1]
    panel.add_pair(p, q)  # two targets on one spot, two sources apart
    assert panel.fit is None
    assert "The target points are on one vertical line" in panel.fit_label.text()


def test_the_wheel_zooms_toward_the_cursor(loaded_window, qtbot):
    from PySide6.QtCore import QPoint, QPointF, Qt
    from PySide6.QtGui import QWheelEvent

    win = loaded_window
    views = _scan_views(win, qtbot)
    view = views[0]
    view.reset_camera()
    plotter = view.plotter
    cam = plotter.renderer.GetActiveCamera()
    ren = plotter.renderer
    # A point a quarter of the width left of the centre, at the focal depth.
    w, h = plotter.width(), plotter.height()
    pos = QPointF(w / 4, h / 2)
    ratio = plotter.devicePixelRatioF()

    def under_cursor():
        ren.SetWorldPoint(*cam.GetFocalPoint(), 1.0)
        ren.WorldToDisplay()
        depth = ren.GetDisplayPoint()[2]
        ren.SetDisplayPoint(pos.x() * ratio, (h - pos.y() - 1) * ratio, depth)
        ren.DisplayToWorld()
        p = np.array(ren.GetWorldPoint())
        return p[:3] / p[3]

    before = under_cursor()
    distance = cam.GetDistance()
    event = QWheelEvent(
        pos,
        QPointF(plotter.mapToGlobal(pos.toPoint())),
        QPoint(0, 0),
        QPoint(0, 120),
        Qt.MouseButton.NoButton,
        Qt.KeyboardModifier.NoModifier,
        Qt.ScrollPhase.NoScrollPhase,
        False,
    )
    plotter.wheelEvent(event)
    assert cam.GetDistance() < distance * 0.9
    # What was under the cursor is still under it.
    assert np.linalg.norm(under_cursor() - before) < 0.02 * distance


def test_two_pairs_on_one_stem_warn_of_a_weak_turn(loaded_window):
    panel = loaded_window.manual_panel
    panel.levelled.setChecked(True)
    T = _truth_local(loaded_window)
    # Two points 3 m apart up a stem that leans 10 cm: the heading hangs on that.
    src = np.array([[0.0, 0.0, 0.0], [0.1, 0.0, 3.0]])
    for a, b in zip(src @ T[:3, :3].T + T[:3, 3], src, strict=True):
        panel.add_pair(a, b)
    assert "Weak turn" in panel.fit_label.text()
    # A third point 2 m out in the crown holds the turn.
    far = np.array([2.0, 0.5, 4.0])
    panel.add_pair(T[:3, :3] @ far + T[:3, 3], far)
    assert "Achievable RMS" in panel.fit_label.text()
    assert "Weak turn" not in panel.fit_label.text()


def test_the_wheel_over_the_turn_scrolls_the_dock_until_it_is_clicked(
    loaded_window, qtbot
):
    from PySide6.QtCore import QPoint, QPointF, Qt
    from PySide6.QtGui import QWheelEvent
    from PySide6.QtWidgets import QApplication

    win = loaded_window
    panel = win.manual_panel
    win.docks["manual"].raise_()
    qtbot.waitUntil(panel.isVisible)
    panel.resize(panel.width(), 200)  # short enough to scroll
    bar = panel.verticalScrollBar()
    qtbot.waitUntil(lambda: bar.maximum() > 0)
    bar.setValue(0)
    panel.setFocus()

    def wheel(widget, notches: int) -> None:
        pos = QPointF(widget.width() / 2, widget.height() / 2)
        event = QWheelEvent(
            pos,
            QPointF(widget.mapToGlobal(pos.toPoint())),
            QPoint(0, 0),
            QPoint(0, 120 * notches),
            Qt.MouseButton.NoButton,
            Qt.KeyboardModifier.NoModifier,
            Qt.ScrollPhase.NoScrollPhase,
            False,
        )
        QApplication.sendEvent(widget, event)

    turn = panel.yaw.value()
    wheel(panel.yaw, -3)  # scroll down over the unfocused Turn box
    assert panel.yaw.value() == turn
    assert bar.value() > 0
    win.activateWindow()
    panel.yaw.setFocus()  # clicked: now the wheel turns
    qtbot.waitUntil(panel.yaw.hasFocus)
    wheel(panel.yaw, 1)
    assert panel.yaw.value() != turn


def test_a_transform_file_is_read_only_when_it_is_small(
    loaded_window, tmp_path, errors
):
    panel = loaded_window.manual_panel
    errors.watch(loaded_window.session)
    small = tmp_path / "t.txt"
    small.write_text("1 0 0 1\n0 1 0 2\n0 0 1 3\n0 0 0 1\n")
    panel.load_transform(small)
    assert panel.text.toPlainText().startswith("1 0 0 1")
    big = tmp_path / "scan.txt"  # a text scan picked by mistake
    big.write_text("1.0 2.0 3.0\n" * 200_000)
    panel.load_transform(big)
    assert panel.text.toPlainText().startswith("1 0 0 1")  # kept
    assert "transform file" in errors[-1]
