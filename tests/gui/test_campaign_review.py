"""A campaign tree opened in the app from its stored result, never registered again.

Driven headless through the window: select a tree (its stored pose, metrics and
verdict show, only the load job runs), list its scans and links, show another link,
accept and export; Fine from the stored pose separates and refines, nothing else.
"""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest

from amrst.campaign.review import exported_path

SAMPLE = Path(__file__).resolve().parents[2] / "resources" / "sample"
TINY_TREE = Path(__file__).resolve().parents[1] / "data" / "tiny_tree" / "tree.ply"


@pytest.fixture(scope="module")
def campaign(tmp_path_factory) -> Path:
    """T01: the sample pair, T02: three simulated scans, T04: two scans of one E57
    file (these three run), T03: not run."""
    from _writers import write_e57

    from amrst import io
    from amrst.campaign import init_campaign, load_campaign
    from amrst.campaign.batch import pending_trees
    from amrst.campaign.run import run_tree
    from amrst.multiscan.simulate import simulate_scans, write_scans

    root = tmp_path_factory.mktemp("campaign")
    for tree in ("T01", "T03"):
        (root / tree).mkdir()
        for name in ("target.ply", "source.ply"):
            shutil.copy(SAMPLE / name, root / tree / name)
    sim = simulate_scans(io.read(TINY_TREE), 3, seed=0, res_deg=0.2)
    write_scans(sim, root / "T02")
    (root / "T04").mkdir()
    write_e57(root / "T04" / "plot.e57", sim.scans[:2])
    init_campaign(root)
    todo, _, doc = pending_trees(load_campaign(root))
    for entry, stamp in todo:
        if entry.id != "T03":
            assert run_tree(str(root), entry, doc, stamp)["ok"]
    return root


def _doc(root: Path, tree: str, name: str) -> dict:
    return json.loads((root / "results" / tree / name).read_text(encoding="utf-8"))


def _show(qtbot, panel, session, tree: str) -> None:
    """Select a tree; wait until its scans (and result) are shown."""
    with qtbot.waitSignal(session.busy_changed, timeout=20_000):
        panel.select_tree(tree)  # the load job starts
    qtbot.waitUntil(lambda: not session.busy, timeout=20_000)


@pytest.mark.slow
def test_select_review_accept_export_a_stored_tree(
    make_main_window, qtbot, campaign, tmp_path, discard_answers
):
    from amrst import io
    from amrst.types import invert_transform

    win = make_main_window()
    session, panel = win.session, win.campaign_panel
    steps: list[str] = []
    session.step_started.connect(steps.append)
    assert panel.open_campaign(campaign)

    _show(qtbot, panel, session, "T01")
    assert steps == ["load"]  # no registration step ran
    assert set(session.timings) == {"load"}
    assert all(session.is_done(s) for s in ("match", "coarse", "fine"))
    assert not session.is_stale("fine")
    stored_T = np.asarray(_doc(campaign, "T01", "transform.json")["T_target_source"])
    np.testing.assert_allclose(session.world(session.final_transform), stored_T)
    metrics = _doc(campaign, "T01", "metrics.json")
    assert session.verdict.status == metrics["verdict"]["status"]
    assert session.metrics["fine"].rmse_overlap_m == metrics["fine"]["rmse_overlap_m"]
    assert session.tree["merged"].height_m == metrics["tree"]["merged"]["height_m"]
    # The Quality table and the verdict read the stored overlap figures and strength.
    quality = session.stage_quality("fine")
    assert quality is not None
    stored = metrics["quality"]["distance"]
    assert quality.overlap.median_m == pytest.approx(stored["median_m"])
    assert quality.overlap.within_2cm_fraction == pytest.approx(
        stored["within_2cm_fraction"]
    )
    assert quality.strength.values["rz"] == pytest.approx(metrics["strength"]["rz"])
    # The overlay shows the pose (from the next turn of the event loop).
    qtbot.waitUntil(lambda: win.tabs.currentWidget() is win.registration)

    # three scans: every scan and link listed; another link shows its two scans
    steps.clear()
    _show(qtbot, panel, session, "T02")
    assert steps == ["load"]
    listing = panel.tree_scans
    scans = _doc(campaign, "T02", "scans.json")
    assert listing.scans.rowCount() == 3
    assert listing.scans.item(0, 2).text() == "reference"
    assert listing.scans.item(2, 2).text() == "via " + " → ".join(
        map(str, scans["scans"][2]["path"])
    )
    assert [listing.links.item(i, 1).text() for i in range(3)] == [
        link["status"] for link in scans["links"]
    ]
    row = next(
        i
        for i, link in enumerate(scans["links"])
        if {link["target"], link["source"]} == {1, 2}
    )
    with qtbot.waitSignal(session.busy_changed, timeout=20_000):
        listing.links.selectRow(row)
    qtbot.waitUntil(lambda: not session.busy, timeout=20_000)
    link = scans["links"][row]
    assert session.path("target").name == f"scan_{link['target']}.ply"
    assert session.path("source").name == f"scan_{link['source']}.ply"
    poses = [np.asarray(s["T_reference_scan"]) for s in scans["scans"]]
    expected = invert_transform(poses[link["target"]]) @ poses[link["source"]]
    np.testing.assert_allclose(
        session.world(session.final_transform), expected, atol=1e-9
    )
    assert steps == ["load", "load"]
    # the tree's truth file, for this link: its errors show as for a case
    err = session.truth_errors()["fine"]
    assert err.rotation_error_deg < 1.0
    assert err.gt_rmse_m < 0.05

    # scans of one E57 file (FILE#k in the manifest) open the same way
    _show(qtbot, panel, session, "T04")
    assert session.path("target").name == "plot.e57#0"
    assert session.stored is not None
    assert session.is_done("fine")

    # a tree not run: its scans, no result
    _show(qtbot, panel, session, "T03")
    assert session.final_transform is None
    assert session.stored is None
    assert session.truth is None  # the last tree's truth went with it
    assert [listing.scans.item(k, 2).text() for k in range(2)] == [
        "not run",
        "reference",  # target.ply, the second in name order
    ]

    # accept (on disk at once) and export, from the stored result
    _show(qtbot, panel, session, "T01")
    panel.decide("accepted")
    assert _doc(campaign, "T01", "review.json")["decision"] == "accepted"
    out = tmp_path / "export"
    with qtbot.waitSignal(session.exported, timeout=60_000):
        session.export(out)
    exported = json.loads((out / "transform.json").read_text(encoding="utf-8"))
    np.testing.assert_allclose(exported["T_target_source"], stored_T)
    panel.export_accepted()
    qtbot.waitUntil(lambda: panel.job is None, timeout=60_000)
    assert str(campaign / "results") in panel.status.text()  # says where it wrote
    merged = io.read(campaign / "results" / "T01" / "merged.ply")
    assert set(np.unique(merged.attributes["scan_id"])) == {0, 1}
    assert panel.state_of("T01") == "accepted"  # the export is on record
    assert exported_path(panel.campaign, "T01") is not None
    assert discard_answers.asked == []  # a stored result is never "unexported"
    panel.decide("clear")  # a decision can be taken back
    assert panel.state_of("T01") == "registered"
    panel.decide("accepted")

    # Fine from the stored pose: separate, then refine; no match, no new coarse
    steps.clear()
    with qtbot.waitSignal(session.fine_finished, timeout=90_000):
        session.run_step("fine")
    qtbot.waitUntil(lambda: not session.busy, timeout=5_000)
    assert steps == ["separate", "fine"]
    assert session.stored is None  # the new fine result replaced the stored one
    moved = session.world(session.final_transform)
    assert np.linalg.norm(moved[:3, 3] - stored_T[:3, 3]) < 0.05


def test_stored_tree_and_link_list(campaign):
    from amrst.campaign import load_campaign
    from amrst.campaign.review import batch_state
    from amrst.campaign.stored import read_stored_tree
    from amrst_gui.panels.campaign_scans import link_cells, scan_how

    c = load_campaign(campaign)
    assert read_stored_tree(c, "T03") is None  # not run: nothing stored
    tree = read_stored_tree(c, "T02")
    assert tree is not None
    assert (len(tree.scans), len(tree.links)) == (3, 3)
    doc = _doc(campaign, "T02", "scans.json")
    assert [c[1] for c in link_cells(tree)] == [d["status"] for d in doc["links"]]
    assert [c[5] == "yes" for c in link_cells(tree)] == [
        d["in_tree"] for d in doc["links"]
    ]
    assert scan_how(tree, 0, 0) == "reference"
    assert scan_how(None, 1, 0) == "not run"
    for k in (1, 2):
        assert scan_how(tree, k, 0).startswith("via 0 → ")
    # a link's pose is the one between both scans' stored poses, either way round
    T12, T21 = tree.link_transform(1, 2), tree.link_transform(2, 1)
    np.testing.assert_allclose(T12 @ T21, np.eye(4), atol=1e-9)
    assert tree.link(2, 1) is tree.link(1, 2)
    result = tree.link_result(0, 1)
    assert result is not None
    assert result.verdict["status"] == "registered"
    # the pair tree reads its verdict from the pair's own metrics.json
    pair = read_stored_tree(c, "T01").link_result(1, 0)
    assert pair.verdict == _doc(campaign, "T01", "metrics.json")["verdict"]
    # while a batch runs: running only when a worker has it, queued before
    assert batch_state("not run", "a", {"a"}, set()) == "queued"
    assert batch_state("not run", "a", set(), {"a"}) == "running"
    assert batch_state("registered", "a", set(), set()) == "registered"


def test_app_opens_a_campaign_from_the_command_line(
    make_main_window, qtbot, campaign, tmp_path, capsys
):
    from amrst_gui.__main__ import _open_campaign, parse_args

    args = parse_args(["--campaign", str(campaign), "--tree", "T02"])
    win = make_main_window()
    assert not _open_campaign(win, tmp_path / "nothing", None)
    assert capsys.readouterr().err.startswith("amrst-gui: ")  # one line, no traceback
    assert not _open_campaign(win, campaign, "T99")
    assert "no tree 'T99'" in capsys.readouterr().err
    with qtbot.waitSignal(win.session.fine_finished, timeout=20_000):
        assert _open_campaign(win, args.campaign, args.tree)
    qtbot.waitUntil(lambda: not win.session.busy, timeout=5_000)
    assert win.campaign_panel.selected_ids() == ["T02"]
    assert "T02" in win.session.stored.label


@pytest.mark.slow
def test_manual_recovery_from_a_stored_result(make_main_window, qtbot, campaign):
    from amrst.stages.candidates import Origin

    win = make_main_window()
    session, panel = win.session, win.campaign_panel
    assert panel.open_campaign(campaign)
    _show(qtbot, panel, session, "T02")
    stored = session.world(session.final_transform)
    steps: list[str] = []
    session.step_started.connect(steps.append)
    # a typed pose 3 cm off the stored one: scored as a candidate, first in the list
    T = session.final_transform.copy()
    T[0, 3] += 0.03
    with qtbot.waitSignal(session.matches_changed, timeout=60_000):
        session.add_manual_pose(T, "typed")
    qtbot.waitUntil(lambda: not session.busy, timeout=5_000)
    assert steps == ["separate", "manual"]  # no skeleton, no match
    assert [c.origin for c in session.matches] == [Origin.MANUAL, Origin.TETRAHEDRA]
    assert session.stored is not None  # still shown until a step replaces it
    with qtbot.waitSignal(session.coarse_accepted, timeout=60_000):
        session.accept_coarse()
    assert steps[2:] == ["coarse"]
    assert session.accepted_coarse.candidate.origin == Origin.MANUAL
    assert session.stored is None  # the accepted manual pose replaced it
    with qtbot.waitSignal(session.fine_finished, timeout=90_000):
        session.run_step("fine")
    qtbot.waitUntil(lambda: not session.busy, timeout=5_000)
    assert steps[3:] == ["fine"]
    # Fine from the manual pose comes back to the stored one (within 1 cm)
    moved = session.world(session.final_transform)
    assert abs(moved[0, 3] - stored[0, 3]) < 0.01


def test_batch_tracker_running_only_between_worker_events():
    from amrst_gui.panels.campaign_rows import BatchTracker

    batch = BatchTracker()
    batch.submit({"A", "B"})
    assert [batch.state("not run", t) for t in "AB"] == ["queued", "queued"]
    batch.start("A")
    assert [batch.state("not run", t) for t in "AB"] == ["running", "queued"]
    assert batch.end("A")  # its files are written: its row is read again
    assert not batch.end("A")  # its result after its worker's event: once only
    assert batch.state("registered", "A") == "registered"
    batch.start("A")  # a late event changes nothing
    assert batch.state("registered", "A") == "registered"
    # a result before its worker's event (a fast failure): finished, never running
    assert batch.end("B")
    batch.start("B")
    assert batch.state("failed", "B") == "failed"
    batch.clear()
    assert batch.state("not run", "A") == "not run"


def test_stored_quality_reads_nulls_and_old_names_without_failing():
    import math

    from amrst_gui.stored_result import pose_quality

    assert pose_quality(None, None) is None
    assert pose_quality({"distance": "broken"}, None) is None
    q = pose_quality(
        {
            "distance": {
                "median_m": None,
                "p95_m": "x",
                "within_2cm_fraction": 0.5,
                "overlap_fraction": 0.4,
                "n_points": 120,
            }
        },
        {"rz": None, "tx": 0.6},
    )
    assert q is not None
    assert math.isnan(q.overlap.median_m)
    assert math.isnan(q.overlap.p95_m)
    assert q.overlap.within_2cm_fraction == 0.5
    assert q.overlap.n_points_measured == 120
    assert q.strength.values["tx"] == 0.6
    assert math.isnan(q.strength.values["rz"])


def test_the_views_end_on_the_tree_chosen_last_and_the_selection_holds(
    make_main_window, qtbot, campaign
):
    win = make_main_window()
    session, panel = win.session, win.campaign_panel
    assert panel.open_campaign(campaign)
    # Two trees chosen in a row: the second waits for the first one's scans.
    with qtbot.waitSignal(session.busy_changed, timeout=20_000):
        panel.select_tree("T01")
    panel.select_tree("T02")
    qtbot.waitUntil(
        lambda: (
            not session.busy
            and session.path("target") is not None
            and session.path("target").parent.name == "T02"
        ),
        timeout=40_000,
    )
    # A redraw of the table keeps exactly the trees selected, wherever they move.
    qtbot.waitUntil(lambda: not session.busy, timeout=20_000)
    panel.table.selectAll()
    chosen = set(panel.selected_ids())
    assert len(chosen) == 4
    panel.refresh()
    assert set(panel.selected_ids()) == chosen
    # A long message wraps: the dock never widens past a laptop screen.
    panel._say("Exported to " + "/very/long/path" * 60)
    assert panel.minimumSizeHint().width() < 700
    # The manifest edited by hand shows at the next refresh; a broken one is said.
    toml = campaign / "campaign.toml"
    text = toml.read_text()
    try:
        panel.select_tree("T03")
        qtbot.waitUntil(lambda: not session.busy, timeout=20_000)
        toml.write_text(text.replace('id = "T03"', 'id = "T03b"'))
        panel.refresh()
        assert "T03b" in {r["tree_id"] for r in panel.rows}
        assert panel.selected_ids() == []  # the tree shown is gone: its listing too
        assert panel.tree_scans.title.text().startswith("Select a tree")
        toml.write_text("[[tree]\n")
        panel.refresh()
        assert "not valid TOML" in panel.status.text()
        assert "T03b" in {r["tree_id"] for r in panel.rows}  # as read before
    finally:
        toml.write_text(text)
    # Another campaign is not opened while this one's batch or export runs.
    panel.job = object()  # as run_stage leaves it while a job runs
    assert not panel.open_campaign(campaign)
    assert "open another when it ends" in panel.status.text()
    panel.job = None


@pytest.mark.slow
def test_a_declined_or_refused_switch_keeps_the_shown_tree_selected(
    make_main_window, qtbot, campaign, discard_answers, monkeypatch
):
    """Another tree clicked but not opened (the technician keeps the unexported
    result, or a step runs): the selection, the listing and Accept stay on the tree
    the views show, never on the row merely clicked."""
    win = make_main_window()
    session, panel = win.session, win.campaign_panel
    monkeypatch.setattr(panel, "confirm", lambda _question: True)
    assert panel.open_campaign(campaign)
    _show(qtbot, panel, session, "T01")
    session.run_step("fine")
    qtbot.waitUntil(lambda: not session.busy, timeout=60_000)
    assert session.has_unexported_result

    def on_t01() -> None:
        assert session.path("target").parent.name == "T01"
        assert panel.selected_ids() == ["T01"]
        assert "<b>T01</b>" in panel.tree_scans.title.text()

    try:
        discard_answers.append(False)  # keep the T01 result
        panel.select_tree("T04")
        assert discard_answers.asked == ["Opening other scans"]
        on_t01()
        panel.accept_button.click()
        assert panel.state_of("T01") == "accepted"
        assert panel.state_of("T04") != "accepted"
        panel.decide("clear")

        # Clicked while a step runs: refused, the same.
        failed: list[str] = []
        session.failed.connect(failed.append)
        session.run_step("fine")
        panel.select_tree("T04")
        assert failed
        assert "runs" in failed[-1]
        on_t01()
        qtbot.waitUntil(lambda: not session.busy, timeout=60_000)
        on_t01()
    finally:
        if win.error_box:
            win.error_box.close()
        panel.decide("clear")
