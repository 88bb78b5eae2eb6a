"""The app reads the engine's step table: every step has its code in
``amrst_gui/session.py``, an action, a label; scans are keyed by id, reviews by link."""

from __future__ import annotations

import pytest

from amrst.pipeline.steps import STEP_NAMES


@pytest.mark.parametrize("step", STEP_NAMES)
def test_every_step_of_the_table_has_its_app_code_and_action(make_main_window, step):
    from amrst_gui import steps
    from amrst_gui.session import Session

    for part in ("start", "apply", "done", "summary", "clear"):
        assert callable(getattr(Session, f"_{part}_{step}", None)), (step, part)
    win = make_main_window()
    assert step in win.actions.step_actions
    assert win.actions.step_actions[step].text().startswith(steps.LABELS[step])
    assert not win.session.is_done(step)
    assert win.session.plan(step)[-1] == step


def test_scan_ids_stay_with_their_files_and_the_review_with_its_link(
    loaded_window, qtbot
):
    s = loaded_window.session
    target_id, source_id = s.scan_id("target"), s.scan_id("source")
    assert target_id != source_id
    assert s.cloud("target") is s._scans[target_id].cloud
    s.review.link_review.manual_labels[1] = "kept for this link only"
    s.swap_scans()
    # The files keep their ids, in the other roles; the swapped link has its own
    # (empty) review.
    assert (s.scan_id("target"), s.scan_id("source")) == (source_id, target_id)
    assert s.manual_labels == {}
