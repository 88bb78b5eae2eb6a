"""The technician's judgement, through the real window: the verdict,
Export's override, manual recovery (pairs picked in the views, nudge, typed
transform) and a review that survives a preset change and a re-run."""

from __future__ import annotations

import dataclasses
import json

import numpy as np
import pytest
from _picking import click

from amrst.types import local_transform


def _failing_params(params):
    # Nothing verifies at 5 mm, and the trunk search is off: no candidate verifies,
    # as on scans that share little.
    return dataclasses.replace(
        params,
        coarse=dataclasses.replace(params.coarse, tight_dist_m=0.005),
        trunk=dataclasses.replace(params.trunk, mode="off"),
    )


def _run(qtbot, session, trigger, timeout=60_000):
    with qtbot.waitSignal(
        session.busy_changed, timeout=timeout, check_params_cb=lambda b: not b
    ):
        trigger()


def test_failed_verdict_everywhere_run_all_stops_and_export_asks_after_accept(
    loaded_window, qtbot, errors, override_answers, tmp_path
):
    win = loaded_window
    s = win.session
    errors.watch(s)
    s.set_params(_failing_params(s.params))
    _run(qtbot, s, win.actions.run_all.trigger)
    # Run all stopped before accepting the unverified candidate, and said so.
    assert s.accepted_coarse is None
    assert s.fine is None
    assert errors
    assert "stopped before accepting an unverified candidate" in errors[-1]
    v = s.verdict
    assert v.status == "failed"
    assert "No candidate verifies" in v.reason
    # The same words in the Matches header, the Metrics dock and the status bar.
    assert "Failed" in win.matches_panel.coarse_label.text()
    assert v.reason.split(":")[0] in win.matches_panel.coarse_label.text()
    assert "Failed" in win.metrics_panel.verdict_label.text()
    assert "Failed" in win.status.message.text()

    # The technician accepts it anyway (own decision), then runs Fine: the pose is
    # judged by its own evidence now, and its weak axis is named.
    _run(qtbot, s, win.actions.accept_coarse.trigger)
    _run(qtbot, s, win.actions.run_fine.trigger)
    assert s.fine is not None
    v = s.verdict
    assert v.status == "needs review"
    assert "which you accepted though it does not verify" in v.reason
    assert "rotation about the stem" in v.reason
    # The Strength tab counts its weak axes and shows the one the verdict names.
    metrics = win.metrics_panel
    strength = metrics.strength_table
    assert "weak)" in metrics.tabs.tabText(metrics.tabs.indexOf(strength))
    rz = strength.item(strength.rowCount() - 1, 1)
    assert rz.text().endswith("weak")
    metrics.tabs.setCurrentWidget(strength)  # opened: the weak row is in view
    qtbot.waitUntil(lambda: strength.isVisible())
    shown = strength.viewport().rect()
    assert shown.contains(strength.visualItemRect(rz).center())
    # Export asks; Cancel writes nothing.
    box = win.export_dialog()
    box.folder_edit.setText(str(tmp_path / "out"))
    box.accept()
    assert len(override_answers.asked) == 1
    assert not (tmp_path / "out" / "transform.json").exists()
    # Export anyway: the override and the verdict are in the files.
    override_answers.append(True)
    box = win.export_dialog()
    box.folder_edit.setText(str(tmp_path / "out"))
    with qtbot.waitSignal(s.exported, timeout=30_000):
        box.accept()
    data = json.loads((tmp_path / "out" / "transform.json").read_text())
    assert data["verdict"]["status"] == "needs review"
    assert data["override"]["verdict_status"] == "needs review"
    metrics = json.loads((tmp_path / "out" / "metrics.json").read_text())
    assert metrics["verdict"]["status"] == "needs review"


def _off_axis(src, idx):
    r = np.hypot(*(src[idx, :2] - np.median(src[idx, :2], axis=0)).T)
    order = idx[np.argsort(r)]
    return order[len(order) // 2 :]


def _truth_local(win):
    s = win.session
    return local_transform(s.truth, s.cloud("target"), s.cloud("source"))


def test_three_pairs_picked_in_the_views_recover_the_pose_then_fine(
    loaded_window, qtbot, errors
):
    from scipy.spatial import cKDTree

    win = loaded_window
    s = win.session
    errors.watch(s)
    panel = win.manual_panel
    win.tabs.setCurrentIndex(0)  # the Scans tab: target | source
    views = win.scans_area.panes["target"].view, win.scans_area.panes["source"].view
    qtbot.waitUntil(lambda: all(v.isVisible() for v in views))
    panel.levelled.setChecked(False)  # a full rotation from 3 pairs
    panel.set_picking(True)
    T_true = _truth_local(win)
    tgt, src = s.cloud("target").xyz, s.cloud("source").xyz
    moved = src @ T_true[:3, :3].T + T_true[:3, 3]
    d, j = cKDTree(tgt).query(moved)
    # Points both scans hold (within 3 mm): low on the stem, mid, high in the crown.
    good = np.flatnonzero(d < 0.003)
    z = src[good, 2]
    spots = (
        good[z <= np.quantile(z, 0.1)],
        good[(z >= np.quantile(z, 0.45)) & (z <= np.quantile(z, 0.55))],
        # the crown, well off the stem axis (but inside the framed view)
        _off_axis(src, good[z >= np.quantile(z, 0.8)]),
    )
    picked = 0
    for spot in spots:
        for k in spot[:40]:
            before = len(panel.pairs)
            click(views[0], tgt[j[k]])
            click(views[1], src[k])
            if len(panel.pairs) > before:
                a, b = panel.pairs[-1]
                # A click snaps to the front point under the cursor: keep the pair if
                # the two snapped points are the same spot of the tree.
                if np.linalg.norm(b @ T_true[:3, :3].T + T_true[:3, 3] - a) < 0.004:
                    picked += 1
                    break
                panel.undo()
    assert picked == 3, "the views' picking did not snap to the clicked points"
    assert panel.table.rowCount() == 3
    fit = panel.fit
    assert fit is not None
    # Before Fine: within 1 cm of the truth on the source points.
    err = np.linalg.norm(
        (src @ fit.T_target_source[:3, :3].T + fit.T_target_source[:3, 3]) - moved,
        axis=1,
    )
    assert np.sqrt(np.mean(err**2)) < 0.01
    # The pose joins the candidate list as "manual", first, scored like the others.
    with qtbot.waitSignal(s.matches_changed, timeout=30_000):
        panel.use_pairs.click()
    qtbot.waitUntil(lambda: not s.busy)
    top = s.matches[0]
    assert top.origin == "manual"
    assert top.score > 0.45
    _run(qtbot, s, win.actions.accept_coarse.trigger)
    assert s.accepted_coarse.candidate.origin == "manual"
    _run(qtbot, s, win.actions.run_fine.trigger)
    assert not errors
    assert s.truth_errors()["fine"].gt_rmse_m < 0.002
    assert s.verdict.status == "registered"
    qtbot.waitUntil(lambda: win.tabs.currentIndex() == 1)  # the overlay, after Fine


def test_nudge_moves_the_live_score(loaded_window, qtbot):
    win = loaded_window
    s = win.session
    panel = win.manual_panel
    win.docks["manual"].raise_()  # the score is computed where it is seen
    qtbot.waitUntil(panel.isVisible)
    typed = _truth_local(win)
    # Two levelled pairs from the truth: the base pose of the nudge.
    src = s.cloud("source").xyz[[0, len(s.cloud("source")) // 2]]
    tgt = src @ typed[:3, :3].T + typed[:3, 3]
    for a, b in zip(tgt, src, strict=True):
        panel.add_pair(a, b)
    right = panel.live_score(panel.nudged_pose())[1]
    panel.yaw.setValue(25.0)
    turned = panel.live_score(panel.nudged_pose())[1]
    assert f"{turned:.0%}" in panel.score_label.text()
    assert turned < right - 0.2
    assert s.manual_preview is not None
    panel.yaw.setValue(0.0)
    panel.shift[0].setValue(30.0)
    assert panel.live_score(panel.nudged_pose())[1] < right - 0.2


def test_a_typed_transform_becomes_the_candidate_fine_starts_from(
    loaded_window, qtbot, errors
):
    win = loaded_window
    s = win.session
    errors.watch(s)
    panel = win.manual_panel
    panel.text.setPlainText("1 2 3\n4 5 6")
    panel.use_typed.click()
    assert errors
    assert "4 rows of 4" in errors[-1]
    errors.clear()
    # transform.txt's format, world frame.
    panel.text.setPlainText(
        "\n".join(" ".join(f"{v:.10f}" for v in r) for r in s.truth)
    )
    with qtbot.waitSignal(s.matches_changed, timeout=30_000):
        panel.use_typed.click()
    qtbot.waitUntil(lambda: not s.busy)
    cand = s.matches[0]
    assert cand.origin == "manual"
    np.testing.assert_allclose(cand.T_match, _truth_local(win), atol=1e-8)
    _run(qtbot, s, win.actions.accept_coarse.trigger)  # runs Match first
    _run(qtbot, s, win.actions.run_fine.trigger)
    assert not errors
    assert s.accepted_coarse.candidate.origin == "manual"
    assert s.truth_errors()["fine"].gt_rmse_m < 0.005


@pytest.mark.parametrize("preset", ["Leaf-on broadleaf"])
def test_rejections_and_manual_poses_survive_a_preset_change_and_rerun(
    loaded_window, qtbot, caplog, preset
):
    from amrst import params as params_io
    from amrst.stages.coarse import same_solution

    win = loaded_window
    s = win.session
    _run(qtbot, s, win.actions.match.trigger)
    first = s.matches[0]
    s.reject_match(first.id)
    win.manual_panel.text.setPlainText(
        json.dumps({"T_target_source": s.truth.tolist()})
    )
    _run(qtbot, s, win.manual_panel.use_typed.click)
    n_manual = len(s.manual_candidates)
    s.set_params(params_io.load_preset(preset))
    with caplog.at_level("INFO", logger="amrst_gui.session"):
        _run(qtbot, s, win.actions.run_all.trigger)
    assert "Review carried over" in caplog.text
    # The rejected pose is still rejected, under its new id, and not used.
    centre = s.match_result.source_centre
    again = [
        c
        for c in s.matches
        if same_solution(c.T_target_source, first.T_target_source, centre)
    ]
    assert again
    assert all(c.id in s.rejected for c in again)
    assert f"{len(s.rejected)} rejected" in win.matches_panel.coarse_label.text()
    assert len(s.manual_candidates) == n_manual
    # The rejected pose was the right one: nothing else verifies, so Run all stops
    # instead of re-accepting it (the README's promise).
    assert s.accepted_coarse is None
    assert s.verdict.status == "failed"


def test_rerunning_fine_from_a_result_nobody_wants_does_not_ask(
    loaded_window, qtbot, discard_answers
):
    win = loaded_window
    s = win.session
    s.set_params(_failing_params(s.params))
    _run(qtbot, s, win.actions.match.trigger)
    _run(qtbot, s, win.actions.accept_coarse.trigger)
    _run(qtbot, s, win.actions.run_fine.trigger)
    assert "which you accepted" in s.verdict.reason
    s.reject_match(s.accepted_coarse.candidate.id)
    _run(qtbot, s, win.actions.accept_coarse.trigger)
    _run(qtbot, s, win.actions.run_fine.trigger)
    assert discard_answers.asked == []
