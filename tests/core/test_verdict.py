"""The verdict: registered / needs review / failed, from real coarse choices."""

from __future__ import annotations

import numpy as np

from amrst.review import verdict
from amrst.stages.coarse import Candidate, CandidateList, choose_coarse


def _cand(cid, score, origin="tetrahedra", polished=True, precise=float("nan")):
    T = np.eye(4)
    T[0, 3] = cid  # distinct poses
    return Candidate(
        id=cid, rank=cid + 1, score=score, raw_score=score, support=1, volume_m3=1.0,
        edge_error=0.01, svd_residual_m=0.01, target_idx=np.arange(4),
        source_idx=np.arange(4), T_match=T, T_target_source=T, polished=polished,
        explanation="", origin=origin, precise_score=precise,
    )  # fmt: skip


def _judge(cands, rejected=frozenset(), fine=None):
    lst = CandidateList(tuple(cands), len(cands))
    try:
        coarse = choose_coarse(lst, rejected)
    except Exception as exc:  # RegistrationFailed: no coarse left
        return verdict.judge(None, candidates=cands, no_coarse_message=str(exc))
    return verdict.judge(coarse, candidates=cands, fine=fine)


def test_a_clear_verified_winner_is_registered():
    v = _judge([_cand(0, 0.66), _cand(1, 0.05)])
    assert v.status == verdict.REGISTERED
    assert v.ok
    assert "66%" in v.reason
    assert "Fine" in v.next_step


def test_an_unverified_automatic_winner_is_failed_with_the_way_out():
    v = _judge([_cand(0, 0.08), _cand(1, 0.05)])
    assert v.status == verdict.FAILED
    assert "No candidate verifies" in v.reason
    assert "by hand" in v.next_step
    assert v.text().startswith("Failed: ")


def test_a_close_runner_up_needs_review():
    v = _judge([_cand(0, 0.50), _cand(1, 0.45)])
    assert v.status == verdict.NEEDS_REVIEW
    assert "confidence" in v.reason.lower()


def test_an_unverified_manual_pose_needs_review_not_failed():
    v = _judge([_cand(0, 0.10, origin="manual"), _cand(1, 0.05)])
    assert v.status == verdict.NEEDS_REVIEW
    assert "manual" in v.reason


def test_all_rejected_or_none_found_is_failed():
    cands = [_cand(0, 0.66)]
    assert _judge(cands, frozenset({0})).status == verdict.FAILED
    none = _judge([])
    assert none.status == verdict.FAILED
    assert "tetrahedra" in none.reason


def test_dict_form_for_the_files():
    d = _judge([_cand(0, 0.66)]).as_dict()
    assert set(d) == {"status", "reason", "next_step"}


def test_a_feature_matcher_pose_is_named_as_such() -> None:
    """The verdict names the source that found the pose: the feature matcher, not the
    tetrahedron matches."""
    from dataclasses import replace

    import numpy as np

    from amrst.stages.candidates import Candidate, CoarseResult, Origin

    cand = Candidate(
        id=1,
        rank=1,
        score=0.35,
        raw_score=0.28,
        support=0,
        volume_m3=float("nan"),
        edge_error=float("nan"),
        svd_residual_m=float("nan"),
        target_idx=np.zeros(0, int),
        source_idx=np.zeros(0, int),
        T_match=np.eye(4),
        T_target_source=np.eye(4),
        polished=True,
        explanation="",
        origin=Origin.FEATURES,
    )
    coarse = CoarseResult(cand, np.eye(4), 0.96, 0.0, "", True)
    text = verdict.judge(coarse).reason
    assert "feature matcher" in text
    assert "tetrahedron" not in text
    tetra = replace(coarse, candidate=replace(cand, origin=Origin.TETRAHEDRA))
    assert "tetrahedron matches" in verdict.judge(tetra).reason


def _manual(overlap, strength=None):
    from amrst.review.overlap import OverlapDistances
    from amrst.review.strength import Strength

    lst = CandidateList((_cand(0, 0.02, origin="manual"),), 1)
    return verdict.judge(
        choose_coarse(lst),
        overlap=OverlapDistances(*overlap),
        strength=None if strength is None else Strength(strength, 1000),
    )


HELD = dict.fromkeys(("tx", "ty", "tz", "rx", "ry", "rz"), 0.4)


def test_a_manual_pose_is_judged_by_its_own_evidence_not_a_share():
    good = _manual((0.008, 0.05, 0.7, 0.4, 5000), HELD)
    assert good.status == verdict.REGISTERED
    assert "0.8 cm" in good.reason
    assert "45%" not in good.reason
    off = _manual((0.03, 0.2, 0.2, 0.4, 5000), HELD)
    assert off.status == verdict.NEEDS_REVIEW
    assert "3.0 cm" in off.reason
    # The reason says what a right pose would show, so the figures are not read
    # as evidence; only what falls short is named.
    assert "A right pose shows a median under 1.5 cm, 50% or more within 2 cm." in (
        off.reason
    )
    few = _manual((0.008, 0.05, 0.7, 0.4, 150), HELD)
    assert few.status == verdict.NEEDS_REVIEW
    assert "A right pose shows 200 or more points seen by both." in few.reason


def test_a_weak_axis_is_named_and_holds_a_manual_pose_back():
    weak = _manual((0.008, 0.05, 0.7, 0.4, 5000), {**HELD, "rz": 0.01})
    assert weak.status == verdict.NEEDS_REVIEW
    assert "rotation about the stem" in weak.reason


def test_a_weak_axis_of_a_verified_pose_is_the_next_step():
    from amrst.review.strength import Strength

    lst = CandidateList((_cand(0, 0.66), _cand(1, 0.05)), 2)
    v = verdict.judge(choose_coarse(lst), strength=Strength({**HELD, "rz": 0.01}, 1000))
    assert v.status == verdict.REGISTERED
    assert "rotation about the stem" in v.next_step


def test_an_unverified_candidate_accepted_by_hand_is_judged_by_its_evidence():
    """The technician may accept a candidate that does not verify: it is judged by
    its distances and strength, as a manual pose is, not failed; left to the
    automatic path, the same candidate fails."""
    from amrst.review.overlap import OverlapDistances
    from amrst.review.strength import Strength

    coarse = choose_coarse(CandidateList((_cand(0, 0.08, origin="trunk"),), 1))
    assert not coarse.verified

    def judged(overlap, by_hand=True):
        return verdict.judge(
            coarse,
            candidates=[coarse.candidate],
            overlap=OverlapDistances(*overlap),
            strength=Strength(HELD, 1000),
            accepted_by_hand=by_hand,
        )

    good = judged((0.008, 0.05, 0.7, 0.4, 5000))
    assert good.status == verdict.REGISTERED
    assert good.reason.startswith(
        "Candidate 1 from the trunk heading search, which you accepted"
    )
    off = judged((0.03, 0.2, 0.2, 0.4, 5000))
    assert off.status == verdict.NEEDS_REVIEW
    assert "A right pose shows" in off.reason
    assert judged((0.008, 0.05, 0.7, 0.4, 5000), by_hand=False).status == (
        verdict.FAILED
    )
