"""The app's clip dialog: open a plot file, click a stem, the tree becomes a scan.

Each sample scan is put in a "plot" beside a copy of itself 20 m away (a second
tree); the dialog cuts the scan's own tree back out of each plot, loads it as
target and source, and the pair then registers as the sample does.
"""

from __future__ import annotations

import numpy as np
from PySide6.QtCore import Qt

from amrst import io
from amrst.types import Cloud
from amrst_gui.clip_dialog import ClipDialog


def _stem(tree: Cloud) -> tuple[float, float]:
    world = tree.world_xyz
    low = world[world[:, 2] < world[:, 2].min() + 1.0]
    return float(np.median(low[:, 0])), float(np.median(low[:, 1]))


def test_clip_two_plots_then_register(
    make_main_window, qtbot, finish, sample_pair, tmp_path
):
    win = make_main_window()
    s = win.session
    target, source, truth = sample_pair
    for role, path in (("target", target), ("source", source)):
        tree = io.read(path)
        plot = Cloud(
            np.vstack([tree.xyz, tree.xyz + np.array([20.0, 0.0, 0.0])]), tree.offset
        )
        io.write(tmp_path / f"{role}_plot.laz", plot)

        dialog = ClipDialog(s, win, out_dir=tmp_path / "clips")
        qtbot.addWidget(dialog)
        dialog.show()
        with qtbot.waitSignal(dialog.overview_ready, timeout=30_000):
            dialog.open_plot(tmp_path / f"{role}_plot.laz")
        click = dialog.view.pixel_of(*_stem(tree)).toPoint()
        qtbot.mouseClick(dialog.view, Qt.MouseButton.LeftButton, pos=click)
        assert dialog.clip_button.isEnabled()
        dialog.radius.setValue(7.0)  # the sample trees lean: crown 6 m off
        dialog.role.setCurrentText(role)
        with qtbot.waitSignal(s.scan_loaded, timeout=30_000) as loaded:
            dialog.clip_button.click()
        assert loaded.args == [role]
        clipped = s.cloud(role)
        assert 0.95 * len(tree) <= len(clipped) <= len(tree)  # not the copy
        if role == "source":  # the same stem again: a new file beside the first
            first = sorted((tmp_path / "clips").glob("source_plot_tree_*"))
            with qtbot.waitSignal(dialog.clipped, timeout=30_000) as again:
                dialog.clip_button.click()
            assert again.args[1] == str(first[0].with_name(f"{first[0].stem}_2.laz"))
            assert len(io.read(first[0])) == len(clipped)  # kept as it was
        dialog.close()

    qtbot.waitUntil(lambda: not s.busy, timeout=10_000)
    s.load_truth(truth)
    qtbot.waitUntil(lambda: s.truth is not None, timeout=10_000)
    finish(s, win.actions.run_all.trigger, "fine_finished")
    assert s.truth_errors()["fine"].gt_rmse_m < 0.05


def test_a_plot_opened_while_another_is_read_shows_its_own_picture(
    make_main_window, qtbot, tmp_path, monkeypatch
):
    import threading

    import amrst.io as aio

    real, gate = aio.read_overview, threading.Event()

    def slow_first(path, *args, **kwargs):
        if "first" in str(path):
            gate.wait(30)
        return real(path, *args, **kwargs)

    monkeypatch.setattr(aio, "read_overview", slow_first)
    win = make_main_window()
    xyz = np.random.default_rng(0).random((2000, 3)) * [1.0, 1.0, 10.0]
    for name, x in (("first", 0.0), ("second", 500.0)):
        io.write(tmp_path / f"{name}.ply", Cloud(xyz + np.array([x, 0.0, 0.0])))
    dialog = ClipDialog(win.session, win, out_dir=tmp_path / "clips")
    qtbot.addWidget(dialog)
    shown: list[float] = []
    dialog.view.show_points = lambda xy: shown.append(float(xy[:, 0].mean()))
    dialog.open_plot(tmp_path / "first.ply")
    with qtbot.waitSignal(dialog.overview_ready, timeout=30_000):
        dialog.open_plot(tmp_path / "second.ply")
    gate.set()  # the first file's overview arrives last...
    qtbot.wait(500)
    assert shown
    assert all(x > 400 for x in shown)  # ... and is never drawn
    assert dialog.file_label.text() == "second.ply"
