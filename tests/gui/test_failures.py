"""Cancel, bad files, closing mid-step: the app keeps its results and keeps working."""

from __future__ import annotations

import dataclasses

import pytest


def test_cancel_a_running_step_keeps_earlier_results(loaded_window, qtbot, errors):
    win = loaded_window
    s = win.session
    errors.watch(s)
    # Cancel as soon as the first step reports progress; Run all always has later
    # steps to drop, so `cancelled` comes whether or not separation stops in time.
    s.progressed.connect(lambda *_: s.cancel())
    with qtbot.waitSignal(s.cancelled, timeout=60_000) as blocker:
        win.actions.run_all.trigger()
    assert "cancel" in blocker.args[0].lower()
    assert not s.busy
    assert not s.is_done("match")
    assert s.has_scans  # the loaded scans are still there
    assert not errors, errors
    assert win.actions.run_all.isEnabled()
    assert "cancel" in win.status.message.text().lower()


def test_busy_disables_job_actions(loaded_window, finish):
    win = loaded_window
    s = win.session
    states = []
    s.step_started.connect(
        lambda _step: states.append([a.isEnabled() for a in win.actions.job_actions()])
    )
    finish(s, win.actions.separate.trigger, "separation_finished")
    assert states
    assert not any(states[0])
    assert win.actions.separate.isEnabled()


def test_corrupt_file_shows_an_error_and_the_app_keeps_working(
    make_main_window, qtbot, tmp_path, sample_pair, errors
):
    win = make_main_window()
    s = win.session
    errors.watch(s)
    bad = tmp_path / "broken.ply"
    bad.write_bytes(
        b"ply\nformat binary_little_endian 1.0\nelement vertex 99\n\x00\x01"
    )
    with qtbot.waitSignal(s.failed, timeout=20_000) as blocker:
        s.load_scan("target", bad)
    assert "broken.ply" in blocker.args[0]
    assert win.error_box is not None
    assert win.error_box.isVisible()
    assert "broken.ply" in win.status.message.text()
    assert "broken.ply" in win.log_panel.plain_text()
    assert s.cloud("target") is None
    assert not s.busy
    # ...and the next, good file loads.
    target, source, _ = sample_pair
    with qtbot.waitSignals([s.scan_loaded] * 2, timeout=20_000):
        win.open_pair(target, source)
    assert s.has_scans
    win.error_box.close()


def test_a_scan_in_millimetres_is_refused_with_what_to_change(
    make_main_window, qtbot, tmp_path, sample_pair, errors
):
    from amrst import io
    from amrst.types import Cloud

    win = make_main_window()
    s = win.session
    errors.watch(s)
    mm = tmp_path / "in_mm.ply"
    io.write(mm, Cloud(io.read(sample_pair[0]).xyz * 1000))
    with qtbot.waitSignal(s.failed, timeout=20_000) as blocker:
        s.load_scan("target", mm)
    assert "in_mm.ply" in blocker.args[0]
    assert "Give the scan in metres" in blocker.args[0]
    assert s.cloud("target") is None
    win.error_box.close()


def test_a_file_of_several_scans_is_not_opened_as_one_scan(
    make_main_window, qtbot, tmp_path, sample_pair, errors
):
    from _writers import write_e57

    from amrst import io

    pytest.importorskip("pye57")
    scans = [io.read(sample_pair[0]), io.read(sample_pair[1])]
    write_e57(tmp_path / "plot.e57", scans)
    win = make_main_window()
    s = win.session
    errors.watch(s)
    with qtbot.waitSignal(s.failed, timeout=20_000) as blocker:
        s.load_scan("target", tmp_path / "plot.e57")
    assert "failed: plot.e57 holds 2 scans, one position each" in blocker.args[0]
    assert "Plot window (File ▸ Open plot…)" in blocker.args[0]
    assert s.cloud("target") is None
    win.error_box.close()
    write_e57(tmp_path / "one.e57", scans[:1])  # a file of one scan opens
    with qtbot.waitSignal(s.scan_loaded, timeout=20_000):
        s.load_scan("target", tmp_path / "one.e57")
    assert len(s.cloud("target")) == len(scans[0])


def test_one_scan_as_target_and_source_is_refused_and_a_fifo_named(
    make_main_window, qtbot, tmp_path, sample_pair, errors
):
    import os
    import shutil

    win = make_main_window()
    s = win.session
    errors.watch(s)
    target = sample_pair[0]
    copy = tmp_path / "copy.ply"  # another file, the same points
    shutil.copyfile(target, copy)
    for source, says in ((target, "the same file"), (copy, "holds the same points")):
        with qtbot.waitSignals([s.scan_loaded] * 2, timeout=20_000):
            s.load_scans(target, source)  # opened: one may be changed next
        s.run_all()  # a copy: the separation step finds it, off the GUI thread
        qtbot.waitUntil(lambda: not s.busy, timeout=20_000)
        assert says in errors[-1]
        assert "Parameters dock" not in errors[-1]  # no setting would help
        assert s.analysis("target") is None
    fifo = tmp_path / "scan.ply"
    os.mkfifo(fifo)
    with qtbot.waitSignal(s.failed, timeout=20_000) as blocker:
        s.load_scan("source", fifo)
    assert "named pipe" in blocker.args[0]
    win.error_box.close()


def test_missing_file_and_running_without_scans_fail_politely(
    make_main_window, qtbot, tmp_path, errors
):
    win = make_main_window()
    errors.watch(win.session)
    win.session.load_scan("source", tmp_path / "nowhere.las")
    win.session.run_step("match")
    assert len(errors) == 2
    assert errors[0].startswith("File not found:")  # the engine's own words
    assert "Open a target and a source" in errors[1]
    # A file of one point is refused when it is opened, not at Separate.
    one = tmp_path / "one.xyz"
    one.write_text("1.0 2.0 3.0\n")
    with qtbot.waitSignal(win.session.failed, timeout=20_000) as blocker:
        win.session.load_scan("source", one)
    assert "one.xyz holds 1 point(s); a scan needs at least 200" in blocker.args[0]
    assert win.session.cloud("source") is None
    win.error_box.close()


def test_close_the_window_mid_step(make_main_window, qtbot, sample_pair):
    target, source, _ = sample_pair
    win = make_main_window()
    s = win.session
    with qtbot.waitSignals([s.scan_loaded] * 2, timeout=20_000):
        win.open_pair(target, source)
    with qtbot.waitSignal(s.progressed, timeout=30_000):
        win.actions.run_all.trigger()
    assert s.busy
    win.close()  # cancels, waits for the worker, closes the plotters
    assert not s.busy
    assert all(view._closed for view in win.views())
    qtbot.wait(0)  # let any late queued signal arrive: nothing may touch the views


def test_closing_during_an_export_closes_once_it_is_written(
    make_main_window, qtbot, monkeypatch
):
    """Export runs to its end: the close waits for it with the window alive."""
    import sys
    import threading

    from amrst_gui.engine_process import ENGINE

    win = make_main_window()
    s = win.session
    release, writing = threading.Event(), threading.Event()

    def export(reporter):  # stands for the export's writing
        writing.set()
        release.wait(30)
        return [], 0.0

    # Where no engine process can start, the call runs in its worker thread, holding
    # the engine as it would in the process.
    ENGINE.stop()
    monkeypatch.setattr(sys, "frozen", True, raising=False)
    win.show()
    s.runner.run_alone("export", export)
    assert writing.wait(30)
    win.close()
    assert win.isVisible()  # not frozen in a wait: the event loop runs
    assert "Closing once Export has written" in win.status.message.text()
    win.close()  # asked again: still one close pending
    release.set()
    qtbot.waitUntil(lambda: not win.isVisible(), timeout=10_000)
    assert not s.busy


@pytest.mark.parametrize("group", ["separate", "fine"])
def test_parameter_change_marks_steps_stale_in_the_actions(
    loaded_window, qtbot, finish, group
):
    win = loaded_window
    s = win.session
    finish(s, win.actions.separate.trigger, "separation_finished")
    panel = win.params_panel
    field = dataclasses.fields(getattr(s.params, group))[-1]
    editor = panel.editors[(group, field.name)]
    assert field.metadata.get("help", "") in editor.toolTip()
    _nudge(editor)
    assert panel.apply_button.isEnabled()
    with qtbot.waitSignal(s.params_changed):
        panel.apply_button.click()
    stale = group == "separate"
    assert win.actions.separate.text().endswith("(stale)") is stale
    assert s.is_stale("separate") is stale


def _nudge(editor) -> None:
    from PySide6.QtWidgets import QCheckBox, QComboBox

    if isinstance(editor, QCheckBox):
        editor.setChecked(not editor.isChecked())
    elif isinstance(editor, QComboBox):
        editor.setCurrentIndex((editor.currentIndex() + 1) % editor.count())
    else:
        value = editor.value()
        editor.setValue(
            value + editor.singleStep() if value < editor.maximum() else value - 1
        )


def test_preset_fills_the_form_and_apply_uses_it(make_main_window, qtbot):
    from amrst import params as params_io
    from amrst_gui import steps

    win = make_main_window()
    panel = win.params_panel
    names = list(params_io.list_presets())
    assert names
    assert panel.preset.count() == len(names) + 1
    leafless = next(n for n in names if "leafless" in n.lower())
    panel.load_preset(leafless)
    assert panel.apply_button.isEnabled()
    with qtbot.waitSignal(win.session.params_changed) as blocker:
        panel.apply_button.click()
    assert steps.values_equal(blocker.args[0], params_io.load_preset(leafless))
    assert not panel.apply_button.isEnabled()
    # Every parameter has an editor with a tooltip.
    for (_group, name), editor in panel.editors.items():
        assert editor.toolTip().startswith(name)


def test_apply_waits_for_the_run_and_refuses_contradictions(loaded_window, finish):
    win = loaded_window
    panel, s = win.params_panel, win.session
    assert not panel.apply_button.isEnabled()  # nothing changed yet
    min_pts = panel.editors[("preprocess", "min_points")]
    max_pts = panel.editors[("preprocess", "max_points")]
    min_pts.setValue(90_000)
    max_pts.setValue(5_000)
    assert panel.apply_button.isEnabled()
    during: list[bool] = []

    def start() -> None:
        s.run_step("separate")
        during.append(panel.apply_button.isEnabled())

    finish(s, start, "separation_finished")
    assert during == [False]  # a run uses one set of parameters
    assert panel.apply_button.isEnabled()  # still changed, and idle again
    before = s.params
    panel.apply()
    # The stage itself refuses the pair, so the form says why and nothing changes.
    assert "Not applied" in panel.state.text()
    assert "preprocess.min_points" in panel.state.text()
    assert s.params is before


def test_the_tree_tab_says_when_the_scans_hold_a_plot(make_main_window, monkeypatch):
    from types import SimpleNamespace

    win = make_main_window()
    panel = win.metrics_panel
    counts = {"target": 8, "source": 10}

    def analysis(role):
        return SimpleNamespace(scene=SimpleNamespace(stems=(None,) * counts[role]))

    monkeypatch.setattr(win.session, "analysis", analysis)
    assert "8 and 10 stems: a plot, not one tree" in panel._plot_note()
    counts.update(target=1, source=3)  # one tree with its neighbours
    assert panel._plot_note() == ""


def test_the_tree_tab_says_so_after_a_run_on_a_plot_s_scans(make_main_window, tmp_path):
    from _plots import plot_pair
    from _run import run_until_idle

    from amrst import io
    from amrst.types import Cloud

    files = [tmp_path / "t.ply", tmp_path / "s.ply"]
    for f, xyz in zip(files, plot_pair()[:2], strict=True):
        io.write(f, Cloud(xyz))
    win = make_main_window()
    s = win.session
    assert not run_until_idle(s, lambda: win.open_pair(*map(str, files)))
    assert not run_until_idle(s, s.run_all)
    assert s.coarse is not None  # the figures are measured
    note = win.metrics_panel.tree_note.text()
    assert "stems: a plot, not one tree" in note
    assert "File ▸ Open plot…" in note


def test_an_automatic_number_takes_no_infinity(qtbot):
    """A float field whose default is automatic takes 'auto' or a finite number."""
    import dataclasses

    from amrst.params import RegistrationParams
    from amrst_gui.panels.param_editors import editor_value, make_editor

    params = RegistrationParams().separate
    field = next(
        f for f in dataclasses.fields(params) if f.name == "intensity_threshold"
    )
    editor = make_editor(field, params.intensity_threshold)
    qtbot.addWidget(editor)
    for text in ("inf", "1e999", "-inf"):
        editor.setText(text)
        with pytest.raises(ValueError, match="finite number or 'auto'"):
            editor_value(editor, params.intensity_threshold)
    editor.setText("0.4")
    assert editor_value(editor, params.intensity_threshold) == 0.4


def test_loading_parameters_says_so(make_main_window, monkeypatch, tmp_path):
    import dataclasses

    from PySide6.QtWidgets import QFileDialog

    from amrst import params as params_io

    win = make_main_window()
    p = win.session.params
    path = tmp_path / "p.json"
    params_io.save_params(
        path, dataclasses.replace(p, fine=dataclasses.replace(p.fine, max_iterations=7))
    )
    monkeypatch.setattr(
        QFileDialog, "getOpenFileName", staticmethod(lambda *_a, **_k: (str(path), ""))
    )
    win.load_params_dialog()
    assert win.session.params.fine.max_iterations == 7
    assert win.status.message.text().startswith(f"Parameters loaded from {path}")
