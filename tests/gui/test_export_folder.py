"""Export never silently overwrites: the dialog starts from the current case's
folder, and an export into a folder holding another pair's export asks first."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

from amrst_gui import dialogs


def _run(qtbot, session, trigger, timeout=60_000):
    with qtbot.waitSignal(
        session.busy_changed, timeout=timeout, check_params_cb=lambda b: not b
    ):
        trigger()


def _case(tmp_path, sample_pair, name):
    """A copy of the sample pair in its own case folder."""
    folder = tmp_path / name
    folder.mkdir()
    for path in sample_pair:
        shutil.copy(path, folder / path.name)
    return [folder / p.name for p in sample_pair]


def test_the_dialog_proposes_the_current_cases_folder(
    make_main_window, qtbot, sample_pair, tmp_path
):
    win = make_main_window()
    s = win.session
    one = _case(tmp_path, sample_pair, "case_one")
    two = _case(tmp_path, sample_pair, "case_two")
    with qtbot.waitSignal(s.scan_loaded, timeout=30_000):
        s.load_scans(one[0], one[1])
    qtbot.waitUntil(lambda: not s.busy)
    box = win.export_dialog()
    assert box.folder().is_relative_to(one[0].parent)
    # The previous case's folder is remembered, but not proposed for another case.
    win.settings.setValue("dirs/export", str(one[0].parent / "registration"))
    box.reject()
    with qtbot.waitSignal(s.scan_loaded, timeout=30_000):
        s.load_scans(two[0], two[1])
    qtbot.waitUntil(lambda: not s.busy)
    box = win.export_dialog()
    assert box.folder() == two[0].parent / dialogs.EXPORT_SUBFOLDER
    box.reject()
    # Within the current case, the folder used last is proposed again.
    mine = two[0].parent / "mine"
    win.settings.setValue("dirs/export", str(mine))
    box = win.export_dialog()
    assert box.folder() == mine
    box.reject()


def test_export_into_another_pairs_folder_asks(
    make_main_window, qtbot, sample_pair, tmp_path, replace_answers
):
    win = make_main_window()
    s = win.session
    one = _case(tmp_path, sample_pair, "case_one")
    two = _case(tmp_path, sample_pair, "case_two")
    out = tmp_path / "out"
    for k, (target, source, _truth) in enumerate((one, two)):
        with qtbot.waitSignal(s.scan_loaded, timeout=30_000):
            s.load_scans(target, source)
        qtbot.waitUntil(lambda: not s.busy)
        _run(qtbot, s, win.actions.run_all.trigger, timeout=120_000)
        assert s.verdict.ok
        box = win.export_dialog()
        box.folder_edit.setText(str(out))
        if k == 0:
            with qtbot.waitSignal(s.exported, timeout=30_000):
                box.accept()
            assert not replace_answers.asked
            first = (out / "transform.json").read_text()
            continue
        # Another pair: asked; Cancel keeps the first export as it was.
        box.accept()
        assert replace_answers.asked == [out]
        assert box.isVisible()
        assert "another run" in box.problem.text()
        assert (out / "transform.json").read_text() == first
        # The session refuses too, whoever calls it.
        s.export(out)
        assert (out / "transform.json").read_text() == first
        # Replace: written over, on purpose.
        replace_answers.append(True)
        with qtbot.waitSignal(s.exported, timeout=30_000):
            box.accept()
        data = json.loads((out / "transform.json").read_text())
        assert data["target_file"] == str(target)
        # The app's metrics.json holds quality and strength as the CLI's does.
        metrics = json.loads((out / "metrics.json").read_text())
        assert set(metrics["strength"]) == {"tx", "ty", "tz", "rx", "ry", "rz"}
        assert metrics["quality"]["distance"]["median_m"] < 0.015
        assert metrics["quality"]["stem_slices"]
        # So does the report, with the strength per axis.
        report = (out / "report.html").read_text()
        assert "Where both scans saw the scene" in report
        assert "turn about the stem" in report


def test_export_never_writes_over_a_scan_open_in_the_app(
    make_main_window, qtbot, sample_pair, tmp_path
):
    """A scan opened from an earlier export folder, under a name the export writes."""
    win = make_main_window()
    s = win.session
    target, source, _truth = _case(tmp_path, sample_pair, "case")
    out = tmp_path / "out"
    out.mkdir()
    shutil.copy(target, out / "merged.ply")
    with qtbot.waitSignal(s.scan_loaded, timeout=30_000):
        s.load_scans(out / "merged.ply", source)
    qtbot.waitUntil(lambda: not s.busy)
    _run(qtbot, s, win.actions.run_all.trigger, timeout=120_000)
    before = (out / "merged.ply").read_bytes()
    failed: list[str] = []
    s.failed.connect(failed.append)
    s.allow_replacing(out)  # even when told it may replace what the folder holds
    s.export(out)
    assert not s.busy
    assert failed
    assert "is a file the run writes" in failed[-1]
    assert (out / "merged.ply").read_bytes() == before


def test_a_folder_no_file_system_takes_is_named_in_the_dialog(
    loaded_window, qtbot, tmp_path
):
    win = loaded_window
    s = win.session
    _run(qtbot, s, win.actions.run_all.trigger, timeout=120_000)
    box = win.export_dialog()
    for folder in (str(tmp_path / ("x" * 300)), str(tmp_path) + "/a\x00b"):
        box.folder_edit.setText(folder)
        box.accept()  # no traceback: the reason, and the dialog stays open
        assert box.isVisible()
        assert "export folder" in box.problem.text()
    assert not s.busy
    box.close()


def test_the_bundled_sample_is_exported_under_home(monkeypatch, tmp_path):
    from amrst.resources import resource_path

    monkeypatch.setenv("HOME", str(tmp_path))  # never into the app's own files
    sample = resource_path("sample")
    proposed = Path(dialogs.export_folder("", sample))
    assert proposed.parent.parent == tmp_path / "AMRST"
    assert proposed.parent.name.startswith("sample-")
    assert proposed.name == dialogs.EXPORT_SUBFOLDER
    # Two such folders of one name are kept apart (here: both among the app's files).
    import amrst.resources

    monkeypatch.setattr(amrst.resources, "resources_root", lambda: tmp_path / "app")
    folders = [tmp_path / "app" / site / "scans" for site in ("a", "b")]
    for folder in folders:
        folder.mkdir(parents=True)
    moved = {dialogs.case_folder(folder) for folder in folders}
    assert len(moved) == 2
    assert all(m.parent == tmp_path / "AMRST" for m in moved)
