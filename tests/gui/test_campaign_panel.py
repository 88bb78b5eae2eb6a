"""The Campaign dock, headless: open, run remaining (real Dask), filter, select,
accept and export, with every decision on disk at once."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest

from amrst.campaign.review import exported_path
from amrst_gui.panels.campaign_panel import CampaignPanel

SAMPLE = Path(__file__).resolve().parents[2] / "resources" / "sample"


def _campaign(root: Path) -> None:
    from amrst.campaign import init_campaign, load_campaign
    from amrst.campaign.batch import pending_trees
    from amrst.campaign.run import run_tree

    for tree in ("T01", "T03"):
        (root / tree).mkdir(parents=True)
        for name in ("target.ply", "source.ply"):
            shutil.copy(SAMPLE / name, root / tree / name)
    (root / "T02").mkdir()
    shutil.copy(SAMPLE / "target.ply", root / "T02" / "a.ply")
    (root / "T02" / "b.ply").write_bytes((SAMPLE / "source.ply").read_bytes()[:5000])
    init_campaign(root)
    todo, _, doc = pending_trees(load_campaign(root))
    entry, stamp = next((e, s) for e, s in todo if e.id == "T03")
    assert run_tree(str(root), entry, doc, stamp)["ok"]  # one tree done before opening


@pytest.mark.slow
def test_open_run_filter_select_accept_export(qtbot, tmp_path):
    from amrst import io

    _campaign(tmp_path)
    panel = CampaignPanel(workers=1)
    qtbot.addWidget(panel)
    assert panel.open_campaign(tmp_path)
    assert panel.job is None  # reads files, never registers
    assert [(r["tree_id"], r["state"]) for r in panel.rows] == [
        ("T03", "registered"),
        ("T01", "not run"),
        ("T02", "not run"),
    ]
    seen: list[dict[str, str]] = []  # every state of the table while the batch runs
    panel.rows_changed.connect(
        lambda: seen.append({r["tree_id"]: r["state"] for r in panel.rows})
    )
    panel.select_tree("T01")  # not run yet: its scans, no links
    assert panel.tree_scans.links.rowCount() == 0
    assert panel.tree_scans.scans.item(0, 2).text() == "not run"
    panel.run_remaining()
    # submitted, not started: queued, never "running" before a worker takes it
    assert panel.state_of("T01") == "queued"
    assert panel.state_of("T02") == "queued"
    qtbot.waitUntil(lambda: panel.job is None, timeout=120_000)
    # the selected tree finished: its link is listed at once
    assert panel.tree_scans.links.rowCount() == 1
    assert panel.tree_scans.links.item(0, 1).text() == "registered"
    running = [sorted(t for t, s in snap.items() if s == "running") for snap in seen]
    # one worker: at most one tree running at a time, and T01 was seen running on it
    # while T02 waited (T01 is submitted first; T02's corrupt scan fails in no time)
    assert max(len(r) for r in running) == 1
    assert any(snap["T01"] == "running" and snap["T02"] == "queued" for snap in seen)
    # those needing a person first: the corrupt tree leads
    assert [(r["tree_id"], r["state"]) for r in panel.rows] == [
        ("T02", "failed"),
        ("T01", "registered"),
        ("T03", "registered"),
    ]
    panel.needs_person.setChecked(True)
    visible = [
        panel.table.item(i, 0).text()
        for i in range(3)
        if not panel.table.isRowHidden(i)
    ]
    assert visible == ["T02"]
    panel.needs_person.setChecked(False)
    panel.filter_edit.setText("T0")
    assert not any(panel.table.isRowHidden(i) for i in range(3))
    panel.table.clearSelection()
    with qtbot.waitSignal(panel.tree_selected) as selected:
        panel.select_tree("T01")
    assert selected.args[0] == "T01"
    assert selected.args[1][0].endswith("T01/target.ply")  # the reference first
    panel.decide("accepted")
    review = json.loads((tmp_path / "results" / "T01" / "review.json").read_text())
    assert review["decision"] == "accepted"  # on disk before anything else happens
    assert panel.state_of("T01") == "accepted"
    assert panel.export_button.isEnabled()
    panel.export_accepted()  # in the background: the window stays free
    assert panel.job is not None
    assert not panel.export_button.isEnabled()
    qtbot.waitUntil(lambda: panel.job is None, timeout=60_000)
    assert "Exported 1 accepted tree(s)" in panel.status.text()
    merged = io.read(tmp_path / "results" / "T01" / "merged.ply")
    assert set(np.unique(merged.attributes["scan_id"])) == {0, 1}
    # the export is on record; the tree stays accepted
    assert panel.state_of("T01") == "accepted"
    assert exported_path(panel.campaign, "T01") is not None
    # a new panel (the app restarted) shows the same states from the folder alone
    again = CampaignPanel()
    qtbot.addWidget(again)
    again.open_campaign(tmp_path)
    assert again.state_of("T01") == "accepted"
    assert again.state_of("T02") == "failed"
    # accepting a tree the batch did not register asks first, in the engine's words
    questions: list[str] = []
    answer = [False]

    def confirm(question: str) -> bool:
        questions.append(question)
        return answer[0]

    again.confirm = confirm
    again.select_tree("T02")  # its run ended in an error: no result to accept
    answer[0] = True
    again.decide("accepted")
    assert again.state_of("T02") == "failed"
    assert questions == []  # nothing to ask about: the engine refuses it at once
    assert "has no result" in again.status.text()


@pytest.mark.slow
def test_a_cancelled_batch_frees_the_dock_only_once_its_cluster_is_gone(
    qtbot, tmp_path, monkeypatch
):
    import distributed

    closed: list[bool] = []

    class Watched(distributed.LocalCluster):
        def close(self, *args, **kwargs):
            closed.append(True)
            return super().close(*args, **kwargs)

    monkeypatch.setattr(distributed, "LocalCluster", Watched)
    _campaign(tmp_path)
    panel = CampaignPanel(workers=1)
    qtbot.addWidget(panel)
    assert panel.open_campaign(tmp_path)
    panel.run_button.click()  # Run remaining
    assert panel.job is not None
    assert panel.run_button.text() == "Cancel"
    panel.run_button.click()  # Cancel
    qtbot.waitUntil(lambda: panel.job is None, timeout=60_000)
    assert closed  # the batch closed its cluster before the dock was freed
    assert panel.run_button.text() == "Run remaining"
    assert panel.run_button.isEnabled()
