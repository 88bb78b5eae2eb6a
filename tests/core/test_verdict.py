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
    """Field case 06 read "Candidate 1 from the tetrahedron matches" for a pose the
    feature matcher found."""
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
