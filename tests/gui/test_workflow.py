"""The whole workflow on the bundled sample, through the real main window."""

from __future__ import annotations

import json

import numpy as np
import pytest
from PySide6.QtCore import Qt

from amrst_gui.panels.matches_panel import CLOSE_COLUMN, COLUMNS


def test_full_workflow_review_accept_refine_export(
    loaded_window, qtbot, finish, tmp_path, content_fraction
):
    win = loaded_window
    s = win.session
    a = win.actions

    # Step by step, each from its action, each in a worker.
    finish(s, a.separate.trigger, "separation_finished")
    assert a.separate.text().endswith("✓")
    wood = win.scans_area.panes["target"].view.scene.layers[0]
    assert wood.key[0] == "wood"  # the views switched to wood/leaf colouring

    finish(s, a.skeleton.trigger, "skeletons_finished")
    finish(s, a.match.trigger, "matches_changed")
    ranked = s.matches
    assert len(ranked) >= 2
    assert win.matches_panel.model.rowCount() == len(ranked)
    model = win.matches_panel.model
    assert model.data(model.index(0, CLOSE_COLUMN)) == "—"  # trunk solutions only
    assert win.matches_panel.table.isColumnHidden(
        CLOSE_COLUMN
    )  # ... so the column is hidden

    # The best match is selected and drawn in both views, same vertex colours.
    assert s.selected_match.id == ranked[0].id
    for view in win.scans_area.views():
        assert {"skeleton", "keypoints", "match_vertices", "match_edges"} <= (
            view.actor_names()
        )
        assert content_fraction(view.plotter) > 0.005
    tv, sv = (v.scene for v in win.scans_area.views())
    t_rgb = next(lay.rgb for lay in tv.layers if lay.name == "match_vertices")
    s_rgb = next(lay.rgb for lay in sv.layers if lay.name == "match_vertices")
    np.testing.assert_array_equal(t_rgb, s_rgb)
    assert len({tuple(c) for c in t_rgb}) == 4

    # Review with the keys: Delete rejects the selected (top) match, R restores
    # it; then reject it for good. The coarse solution moves to the next one.
    win.activateWindow()
    qtbot.waitActive(win)
    table = win.matches_panel.table
    table.setFocus()
    qtbot.waitUntil(table.hasFocus)
    with qtbot.waitSignal(s.review_changed) as blocker:
        qtbot.keyClick(table, Qt.Key_Delete)
    assert blocker.args == [frozenset({ranked[0].id})]
    with qtbot.waitSignal(s.review_changed) as blocker:
        qtbot.keyClick(table, Qt.Key_R)
    assert blocker.args == [frozenset()]
    with qtbot.waitSignal(s.review_changed):
        win.matches_panel.reject_button.click()
    assert s.coarse.candidate.id == ranked[1].id
    assert win.matches_panel.model.status(ranked[0]) == "rejected"
    assert win.matches_panel.model.status(ranked[1]).endswith("coarse")
    s.restore_match(ranked[0].id)  # the best is the coarse solution again...
    assert s.coarse.candidate.id == ranked[0].id
    # ... and selecting another row shows it in the views; Accept coarse takes it.
    win.matches_panel.table.selectRow(1)
    assert s.selected_match.id == ranked[1].id
    t_verts = next(lay for lay in tv.layers if lay.name == "match_vertices")
    new_verts = next(
        lay
        for lay in win.scans_area.views()[0].scene.layers
        if lay.name == "match_vertices"
    )
    assert new_verts.key != t_verts.key

    (coarse,) = finish(s, a.accept_coarse.trigger, "coarse_accepted")
    assert coarse.candidate.id == ranked[1].id
    assert "coarse" in s.metrics
    (fine,) = finish(s, a.run_fine.trigger, "fine_finished")
    assert fine.converged
    assert win.registration.stage == "fine"
    assert "source_points" in win.registration.view.actor_names()
    truth = s.truth_errors()["fine"]
    assert truth.rotation_error_deg < 1.0
    assert truth.gt_rmse_m < 0.05
    assert win.metrics_panel.table.item(0, 1).text() != ""

    # Export through the dialog, then read the files back with amrst.io.
    a.export.trigger()
    box = win.export_box
    assert box.isVisible()
    # A relative folder lands in the case's folder, not in the working directory
    # (the bundled sample's case folder is under ~/AMRST, not among the app's files).
    from amrst_gui.dialogs import case_folder

    box.folder_edit.setText("out")
    assert box.folder() == case_folder(s.path("target").parent) / "out"
    box.folder_edit.setText(str(tmp_path / "out"))
    (paths,) = finish(s, box.accept, "exported")
    _check_export(tmp_path / "out", paths, s)


def _check_export(out, paths, session) -> None:
    from amrst import io

    names = {p.name for p in paths}
    assert all(p.exists() and p.parent == out for p in paths)
    transform_json = next(
        p for p in paths if p.name.endswith(".json") and "transform" in p.name
    )
    data = json.loads(transform_json.read_text())
    T_file = np.asarray(data["T_target_source"], dtype=float)
    np.testing.assert_allclose(
        T_file, session.world(session.final_transform), atol=1e-9
    )
    merged_path = next(p for p in paths if "merged" in p.name)
    merged = io.read(merged_path)
    n_target, n_source = len(session.cloud("target")), len(session.cloud("source"))
    assert len(merged) == n_target + n_source
    scan_id = np.asarray(merged.attributes["scan_id"])
    assert set(np.unique(scan_id).tolist()) == {0, 1}
    assert int(np.count_nonzero(scan_id == scan_id[0])) in (n_target, n_source)
    assert any("params" in n for n in names)
    assert any(n.endswith(".csv") for n in names)


def test_run_all_is_the_automatic_path(loaded_window, finish):
    s = loaded_window.session
    finish(s, loaded_window.actions.run_all.trigger, "fine_finished")
    assert s.accepted_coarse.candidate.id == s.matches[0].id
    assert all(s.is_done(step) for step in ("separate", "skeleton", "match", "fine"))
    assert loaded_window.actions.export.isEnabled()


def test_trunk_search_candidates_in_the_app(loaded_window, qtbot, finish) -> None:
    """With matching made impossible, the match step offers trunk-search candidates:
    the table reads 'trunk', selecting one draws no tetrahedron, rejecting it moves
    the coarse solution on, and fine registration runs from it."""
    import dataclasses

    win = loaded_window
    s = win.session
    a = win.actions
    p = s.params
    s.set_params(
        dataclasses.replace(
            p,
            match=dataclasses.replace(
                p.match, edge_tolerance=0.005, max_residual_m=0.001, retry_relaxed=False
            ),
            # The feature matcher (asked first) would register the sample on its own.
            global_match=dataclasses.replace(p.global_match, mode="off"),
        )
    )
    finish(s, a.separate.trigger, "separation_finished")
    finish(s, a.skeleton.trigger, "skeletons_finished")
    finish(s, a.match.trigger, "matches_changed")
    ranked = s.matches
    assert ranked
    assert all(c.origin == "trunk" for c in ranked)
    model = win.matches_panel.model
    assert model.data(model.index(0, COLUMNS.index("From"))) == "trunk"
    assert model.data(model.index(0, COLUMNS.index("Vol. m³"))) == "—"
    # The close-fit share that orders the headings is shown, best first.
    assert not win.matches_panel.table.isColumnHidden(CLOSE_COLUMN)
    close = [
        float(model.data(model.index(r, CLOSE_COLUMN)).rstrip("%")) for r in range(3)
    ]
    assert close == sorted(close, reverse=True)
    assert close[0] == pytest.approx(100 * ranked[0].precise_score, abs=0.05)
    for view in win.scans_area.views():
        assert "match_vertices" not in view.actor_names()
    assert s.coarse.verified
    # They were verified with the fine settings: changing those makes them stale.
    used = s.params
    s.set_params(
        dataclasses.replace(
            used, fine=dataclasses.replace(used.fine, max_corr_dist_m=0.5)
        )
    )
    assert s.is_stale("match")
    s.set_params(used)
    assert not s.is_stale("match")
    with qtbot.waitSignal(s.review_changed):
        win.matches_panel.reject_button.click()
    assert s.coarse.candidate.id == ranked[1].id
    with qtbot.waitSignal(s.review_changed):
        win.matches_panel.table.selectRow(0)
        win.matches_panel.restore_button.click()
    assert s.coarse.candidate.id == ranked[0].id
    finish(s, a.accept_coarse.trigger, "coarse_accepted")
    (fine,) = finish(s, a.run_fine.trigger, "fine_finished")
    assert fine.converged
    # The full fit the match step made for this solution, not a second run (the
    # engine process sends it back: equal in every field, not the same object).
    made = s.match_result.refined[ranked[0].id]
    for field in dataclasses.fields(fine):
        assert np.array_equal(getattr(fine, field.name), getattr(made, field.name))
    assert s.truth_errors()["fine"].gt_rmse_m < 0.05


def test_the_tree_is_measured_and_exported(loaded_window, finish, tmp_path):
    import math

    win = loaded_window
    s = win.session
    finish(s, s.run_all, "fine_finished")
    values = win.metrics_panel.tree_values()
    merged = values["merged"]
    # The sample tree (ITSMe tree 1) is 22.7 m tall, its stem 15 cm across at 1.3 m.
    assert merged["height_m"] == pytest.approx(22.7, abs=0.2)
    assert merged["dbh_m"] == pytest.approx(15.0, abs=1.5)
    # Each scan sees about half the stem; merged, the circle rests on much more.
    assert merged["stem_arc_deg"] > max(
        values["target"]["stem_arc_deg"], values["source"]["stem_arc_deg"]
    )
    assert win.metrics_panel.tree_table.item(1, 2).text() != ""
    assert "fine transform" in win.metrics_panel.tree_note.text()
    finish(s, lambda: s.export(tmp_path / "out"), "exported")
    tree = json.loads((tmp_path / "out" / "metrics.json").read_text())["tree"]
    assert math.isclose(tree["merged"]["dbh_m"] * 100, merged["dbh_m"])


def test_accept_coarse_keeps_the_chosen_pose_across_a_match_run_again(
    loaded_window, finish
):
    """The matches are stale (a parameter changed): Accept coarse runs Match again
    and takes the candidate of the pose the technician chose, not the new best."""
    import dataclasses

    from amrst.stages.coarse import same_solution

    win = loaded_window
    s = win.session
    finish(s, win.actions.match.trigger, "matches_changed")
    centre = s.review.centre()
    best = s.matches[0].T_target_source
    pick = next(
        c for c in s.matches if not same_solution(c.T_target_source, best, centre)
    )
    s.select_match(pick.id)
    p = s.params
    s.set_params(
        dataclasses.replace(p, match=dataclasses.replace(p.match, edge_tolerance=0.09))
    )
    assert s.is_stale("match")
    (coarse,) = finish(s, win.actions.accept_coarse.trigger, "coarse_accepted")
    assert same_solution(coarse.T_target_source, pick.T_target_source, centre)
