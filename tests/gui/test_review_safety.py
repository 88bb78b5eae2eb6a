"""Review decisions, truth and unexported results are not lost or mixed up."""

from __future__ import annotations

import dataclasses
import json

import pytest
from _run import run_until_idle

from amrst.stages.coarse import same_solution
from amrst_gui.session import Session


def _run(session: Session, start, timeout_ms: int = 90_000) -> list[str]:
    """Start work, spin until idle; return the failure messages."""
    return run_until_idle(session, start, timeout_ms)


@pytest.fixture
def fresh(qapp, sample_pair):
    target, source, _ = sample_pair
    session = Session()
    assert not _run(session, lambda: session.load_scans(target, source))
    yield session
    session.shutdown()


def test_rejections_survive_matching_again(fresh):
    s = fresh
    assert not _run(s, lambda: s.run_step("match"))
    first = s.matches[0]
    s.reject_match(first.id)
    tighter = dataclasses.replace(
        s.params.match, edge_tolerance=s.params.match.edge_tolerance * 0.9
    )
    s.set_params(dataclasses.replace(s.params, match=tighter))
    # Accept coarse re-runs the stale matching; the rejected pose must stay out.
    assert not _run(s, s.accept_coarse)
    centre = s.match_result.source_centre
    again = [
        c
        for c in s.matches
        if same_solution(c.T_target_source, first.T_target_source, centre)
    ]
    assert again, "the tighter matching should find the same solution again"
    assert {c.id for c in again} <= s.rejected
    assert not same_solution(
        s.accepted_coarse.T_target_source, first.T_target_source, centre
    )


def test_a_truth_file_belongs_to_the_scans_it_came_with(fresh, sample_pair):
    s = fresh
    target, source, truth = sample_pair
    s.load_truth(truth)
    assert s.truth is not None
    # Loaded right after the scans were asked for (as open_pair does): kept.
    assert not _run(s, lambda: (s.load_scans(target, source), s.load_truth(truth)))
    assert s.truth is not None
    # Another scan opened later: the old truth no longer describes the pair.
    assert not _run(s, lambda: s.load_scan("source", target))
    assert s.truth is None
    assert s.truth_errors() == {}


def test_export_refuses_a_result_the_parameters_no_longer_describe(fresh, tmp_path):
    s = fresh
    assert not _run(s, s.run_all)
    used = s.params
    wider = dataclasses.replace(used.fine, max_corr_dist_m=0.3)
    s.set_params(dataclasses.replace(used, fine=wider))
    errors = _run(s, lambda: s.export(tmp_path / "stale"))
    assert errors
    assert "out of date" in errors[0]
    assert not (tmp_path / "stale").exists()
    # Rejecting the accepted match makes the result stale too.
    s.set_params(used)
    s.reject_match(s.accepted_coarse.candidate.id)
    assert "out of date" in _run(s, lambda: s.export(tmp_path / "stale"))[0]
    s.restore_match(s.accepted_coarse.candidate.id)
    assert not _run(s, lambda: s.export(tmp_path / "ok"))
    written = json.loads((tmp_path / "ok" / "params.json").read_text())
    assert written["fine"]["max_corr_dist_m"] == used.fine.max_corr_dist_m


def test_unexported_results_are_only_dropped_when_the_user_agrees(fresh, tmp_path):
    s = fresh
    asked: list[str] = []
    answers = [False, False, False]
    s.discard_guard = lambda action, _lost, _keep: (
        asked.append(action) or answers.pop(0)
    )
    assert not _run(s, s.run_all)
    fine = s.fine
    s.run_step("separate")  # refused: the result stays
    s.swap_scans()
    s.load_scan("source", s.path("target"))
    assert not s.busy
    assert s.fine is fine
    assert len(asked) == 3
    assert not _run(s, lambda: s.export(tmp_path / "out"))
    s.swap_scans()  # exported: nothing to ask
    assert len(asked) == 3
    assert s.fine is None


def test_a_rejected_result_is_still_asked_about_before_it_is_replaced(
    make_main_window, sample_pair, discard_answers
):
    """Rejecting the accepted candidate makes the result out of date (the verdict
    shown is *needs review*), yet it is registered and not exported: replacing it
    asks first, and says how to keep it."""
    win = make_main_window()
    s = win.session
    target, source, _ = sample_pair
    assert not _run(s, lambda: s.load_scans(target, source))
    assert not _run(s, s.run_all)
    fine = s.fine
    s.reject_match(s.accepted_coarse.candidate.id)
    assert not s.verdict.ok
    discard_answers.append(False)
    s.run_all()
    assert discard_answers.asked == ["Run all"]
    assert "undo the change (or restore the candidate)" in discard_answers.keep[0]
    assert s.fine is fine


def test_an_empty_file_is_refused_before_the_result_is_put_at_stake(
    make_main_window, sample_pair, discard_answers, tmp_path
):
    """What the path alone says (here: empty) is said before the question whether
    to discard an unexported result: nothing is asked for a file that cannot open."""
    win = make_main_window()
    s = win.session
    target, source, _ = sample_pair
    assert not _run(s, lambda: s.load_scans(target, source))
    assert not _run(s, s.run_all)
    empty = tmp_path / "empty.ply"
    empty.write_bytes(b"")
    errors = _run(s, lambda: s.load_scan("source", empty))
    assert errors
    assert "is empty (0 bytes)" in errors[0]
    assert discard_answers.asked == []
    assert s.fine is not None


def test_parameters_wait_for_the_running_chain(fresh):
    s = fresh
    before = s.params
    other = dataclasses.replace(
        before, preprocess=dataclasses.replace(before.preprocess, voxel_size_m=0.05)
    )
    errors = _run(s, lambda: (s.run_step("match"), s.set_params(other)))
    assert any("change the parameters" in e for e in errors)
    assert s.params is before
    assert not s.is_stale("match")


def test_a_dropped_folder_is_named_as_a_folder(fresh, tmp_path):
    errors = _run(fresh, lambda: fresh.load_scan("target", tmp_path))
    assert errors
    assert "is a folder" in errors[0]


def test_closing_with_an_unexported_result_asks_first(
    make_main_window, sample_pair, discard_answers
):
    win = make_main_window()
    target, source, truth = sample_pair
    assert not _run(win.session, lambda: win.open_pair(target, source, truth))
    assert win.session.truth is not None
    assert not _run(win.session, win.session.run_all)
    discard_answers.append(False)
    assert not win.close()
    assert win.isVisible()
    assert discard_answers.asked == ["Closing AMRST Studio"]


def test_metrics_mark_a_stale_result(loaded_window, finish):
    win = loaded_window
    s = win.session
    finish(s, s.run_all, "fine_finished")
    header = win.metrics_panel.table.horizontalHeaderItem
    assert (header(0).text(), header(1).text()) == ("Coarse", "Fine")
    used = s.params
    s.set_params(
        dataclasses.replace(used, fine=dataclasses.replace(used.fine, max_iterations=5))
    )
    assert (header(0).text(), header(1).text()) == ("Coarse", "Fine (stale)")
    s.set_params(used)
    assert header(1).text() == "Fine"


def test_accepting_coarse_again_during_review_does_not_ask(fresh):
    s = fresh
    asked: list[str] = []
    s.discard_guard = lambda action, _lost, _keep: asked.append(action) or False
    assert not _run(s, s.accept_coarse)
    s.reject_match(s.accepted_coarse.candidate.id)
    assert not _run(s, s.accept_coarse)
    assert asked == []
    assert s.accepted_coarse.candidate.id not in s.rejected


def test_point_pairs_not_saved_are_only_dropped_when_the_user_agrees(
    make_main_window, sample_pair, discard_answers, tmp_path
):
    win = make_main_window()
    s, panel = win.session, win.manual_panel
    target, source, _truth = sample_pair
    assert not _run(s, lambda: win.open_pair(target, source))
    for k in range(3):
        panel.add_pair(s.cloud("target").xyz[k], s.cloud("source").xyz[k])
    discard_answers.append(False)
    win.open_pair(target, source)  # refused: the pairs stay
    assert discard_answers.asked == ["Opening other scans"]
    assert len(panel.pairs) == 3
    discard_answers.append(False)
    assert not win.close()
    assert len(discard_answers.asked) == 2
    panel.save_pairs(tmp_path / "pairs.csv")
    assert not _run(s, lambda: win.open_pair(target, source))  # saved: nothing asked
    assert len(discard_answers.asked) == 2
    assert panel.pairs == []


def test_a_step_asked_for_twice_runs_once_and_says_so(fresh):
    from amrst_gui.steps import plain_label

    s = fresh
    errors = _run(s, lambda: (s.run_step("separate"), s.run_step("separate")))
    assert errors == [
        f"{plain_label('separate')} is running already; wait for it or cancel it (Esc)."
    ]


def test_a_manual_pose_that_separates_again_asks_before_dropping_fine(
    loaded_window, finish, discard_answers
):
    win = loaded_window
    s = win.session
    finish(s, s.run_all, "fine_finished")
    p = s.params
    voxel = p.preprocess.voxel_size_m * 1.5
    s.set_params(
        dataclasses.replace(
            p, preprocess=dataclasses.replace(p.preprocess, voxel_size_m=voxel)
        )
    )
    assert s.is_stale("separate")
    discard_answers.append(False)  # keep the result
    s.add_manual_pose(s.final_transform, "typed")
    assert discard_answers.asked == ["Separate again"] or discard_answers.asked[
        0
    ].endswith("again")
    assert not s.busy
    assert s.fine is not None  # kept


def test_a_truth_dropped_with_the_scans_before_is_said_in_the_status_bar(
    make_main_window, qtbot, sample_pair
):
    win = make_main_window()
    s = win.session
    target, source, truth = sample_pair
    with qtbot.waitSignal(s.scan_loaded, timeout=20_000):
        s.load_scan("target", target)
    qtbot.waitUntil(lambda: not s.busy)
    s.load_truth(truth)
    assert s.truth is not None
    with qtbot.waitSignal(s.scan_loaded, timeout=20_000):
        s.load_scan("source", source)
    qtbot.waitUntil(lambda: not s.busy)
    assert s.truth is None
    assert f"The truth {truth.name} was dropped" in win.status.message.text()
