"""The registration report, through the real window: Export writes
report.html with the verdict and the pictures embedded; View report opens it."""

from __future__ import annotations

import base64
import re


def _images(html: str) -> list[bytes]:
    return [
        base64.b64decode(m)
        for m in re.findall(r'<img [^>]*src="data:image/png;base64,([^"]+)"', html)
    ]


def test_export_writes_the_report_and_view_report_opens_it(
    loaded_window, qtbot, tmp_path, opened_reports
):
    win = loaded_window
    s = win.session
    assert not win.actions.view_report.isEnabled()
    with qtbot.waitSignal(
        s.busy_changed, timeout=90_000, check_params_cb=lambda b: not b
    ):
        win.actions.run_all.trigger()
    assert s.verdict.status == "registered"
    box = win.export_dialog()
    box.folder_edit.setText(str(tmp_path / "out"))
    with qtbot.waitSignal(s.exported, timeout=60_000) as got:
        box.accept()
    report = tmp_path / "out" / "report.html"
    assert report in got.args[0]
    assert s.last_report == report
    html = report.read_text()
    # The verdict, in the words of the app, with its reason.
    assert ">Registered<" in html
    assert s.verdict.reason.split(":")[0] in html
    # Four pictures, embedded: real PNGs of some size (overlay, distance colouring,
    # histogram, stem slices), nothing fetched from elsewhere.
    images = _images(html)
    assert len(images) == 4
    assert all(i.startswith(b"\x89PNG") and len(i) > 5_000 for i in images)
    assert 'src="http' not in html
    assert "src='http" not in html
    # The chosen candidate, the metrics with their meaning, tree, truth, parameters.
    assert "<b>chosen</b>" in html
    assert "NN distance RMS, overlap" in html
    assert "What it means" in html
    assert "Truth: point error RMS" in html
    assert "Tree measurements" in html
    assert "DBH" in html
    assert "max_corr_dist_m" in html
    # The status bar says where it is; View report opens that very file.
    assert "View report" in win.status.message.text()
    assert win.actions.view_report.isEnabled()
    win.actions.view_report.trigger()
    assert opened_reports == [report]
