"""Session alone (no widgets): review decisions, the coarse rule, stale steps."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from _run import run_until_idle

from amrst_gui.session import Session


def _run_until_idle(session: Session, start, timeout_ms: int = 60_000) -> None:
    """Start work, spin until the session is idle again; nothing may fail."""
    errors = run_until_idle(session, start, timeout_ms)
    assert not errors, errors


@pytest.fixture(scope="module")
def matched(qapp, sample_pair):
    """A session that ran the real engine up to matching on the sample pair."""
    target, source, _ = sample_pair
    session = Session()
    _run_until_idle(session, lambda: session.load_scans(target, source))
    _run_until_idle(session, lambda: session.run_step("match"))
    assert len(session.matches) >= 3
    yield session
    session.shutdown()


@pytest.fixture
def session(matched):
    """The matched session with no rejection, the first match selected."""
    for match_id in list(matched.rejected):
        matched.restore_match(match_id)
    matched.review.preferred = None
    matched.select_match(matched.matches[0].id)
    return matched


class _Spy:
    """Records every signal a session emits."""

    NAMES = (
        "review_changed",
        "selection_changed",
        "matches_changed",
        "coarse_accepted",
        "params_changed",
        "failed",
        "busy_changed",
    )

    def __init__(self, session: Session) -> None:
        self.calls: list[tuple[str, tuple]] = []
        for name in self.NAMES:
            getattr(session, name).connect(
                lambda *args, n=name: self.calls.append((n, args))
            )


def test_reject_and_restore_emit_exactly_one_signal(session):
    spy = _Spy(session)
    first = session.matches[0].id
    session.reject_match(first)
    assert spy.calls == [("review_changed", (frozenset({first}),))]
    session.reject_match(first)  # no change: no signal
    assert len(spy.calls) == 1
    session.restore_match(first)
    assert spy.calls[-1] == ("review_changed", (frozenset(),))
    assert len(spy.calls) == 2
    session.restore_match(first)
    assert len(spy.calls) == 2


def test_coarse_follows_best_candidate_not_rejected(session):
    ranked = session.matches
    assert [c.rank for c in ranked] == list(range(1, len(ranked) + 1))
    assert session.coarse.candidate.id == ranked[0].id
    session.reject_match(ranked[0].id)
    assert session.coarse.candidate.id == ranked[1].id
    np.testing.assert_allclose(
        session.coarse.T_target_source, ranked[1].T_target_source, atol=1e-12
    )
    session.reject_match(ranked[2].id)  # a lower one changes nothing
    assert session.coarse.candidate.id == ranked[1].id
    session.restore_match(ranked[0].id)
    assert session.coarse.candidate.id == ranked[0].id


def test_accept_coarse_takes_the_selected_row(session):
    ranked = session.matches
    session.select_match(ranked[1].id)
    _run_until_idle(session, session.accept_coarse)
    assert session.accepted_coarse.candidate.id == ranked[1].id
    assert session.coarse.candidate.id == ranked[1].id
    assert not session.is_stale("coarse")
    # Rejecting the chosen one hands the coarse solution back to the best left.
    session.reject_match(ranked[1].id)
    assert session.coarse.candidate.id == ranked[0].id
    assert session.is_stale("coarse")


def test_accept_coarse_declined_leaves_the_coarse_solution_as_it_was(
    session, monkeypatch
):
    ranked = session.matches
    before = session.coarse.candidate.id
    session.select_match(ranked[2].id)
    monkeypatch.setattr(session, "may_discard", lambda *_a, **_k: False)
    monkeypatch.setattr(session, "_replaces_result", lambda *_a: True)
    session.accept_coarse()  # "discard the result?" - No
    assert not session.busy
    assert session.coarse.candidate.id == before
    assert session.review.preferred is None or session.review.preferred != ranked[2].id


def test_the_coarse_overlay_previews_the_selected_row(session):
    from amrst_gui.views.scene import registration_transform

    ranked = session.matches
    shown = session.accepted_coarse or session.coarse
    session.select_match(shown.candidate.id)
    T, caption = registration_transform(session, "coarse")
    assert caption.startswith("After coarse registration")
    np.testing.assert_array_equal(T, shown.T_target_source)
    assert shown.candidate.id != ranked[2].id
    session.select_match(ranked[2].id)
    T, caption = registration_transform(session, "coarse")
    assert caption.startswith(f"Candidate #{ranked[2].rank}, selected, not accepted")
    np.testing.assert_array_equal(T, ranked[2].T_target_source)
    session.reject_match(ranked[2].id)  # Accept coarse would not take it
    assert registration_transform(session, "coarse")[1].startswith("After coarse")


def test_rejecting_everything_leaves_no_coarse_solution(session):
    for cand in session.matches:
        session.reject_match(cand.id)
    assert session.coarse is None
    assert session.coarse_message
    assert "coarse" not in session.plan("match")


def test_unknown_match_id_is_refused(session):
    with pytest.raises(ValueError, match="no candidate"):
        session.reject_match(-12345)


def test_changing_a_parameter_marks_later_steps_stale(session):
    assert session.is_done("match")
    assert not session.is_stale("match")
    original = session.params
    spy = _Spy(session)
    new_match = dataclasses.replace(
        original.match, edge_tolerance=original.match.edge_tolerance * 0.9
    )
    session.set_params(dataclasses.replace(original, match=new_match))
    try:
        assert spy.calls == [("params_changed", (session.params,))]
        assert not session.is_stale("separate")
        assert not session.is_stale("skeleton")
        assert session.is_stale("match")
        assert session.plan("match") == ["match"]
        assert session.plan("fine") == ["match", "coarse", "fine"]
    finally:
        session.set_params(original)
    assert not session.is_stale("match")


def test_truth_errors_need_a_truth_file(session, sample_pair, tmp_path):
    assert session.truth_errors() == {}
    spy = []
    session.failed.connect(spy.append)
    bad = tmp_path / "truth.json"
    bad.write_text('{"T_target_source": [[1, 0], [0, 1]]}')
    session.load_truth(bad)
    assert spy
    assert "4x4" in spy[0]
    session.load_truth(sample_pair[2])
    errors = session.truth_errors()["coarse"]
    # The sample's easy pair: the best candidate is right to within a degree.
    assert errors.rotation_error_deg < 2.0


def test_every_parameter_group_belongs_to_a_step() -> None:
    """A parameter section no step owns would never mark a result stale."""
    import dataclasses

    from amrst.params import RegistrationParams
    from amrst_gui import steps

    owned = set(steps.groups_for(steps.STEPS[-1]))
    groups = {f.name for f in dataclasses.fields(RegistrationParams)}
    assert groups <= owned, groups - owned
