"""A refinement of a manual pose replaces it only when it stays the same solution."""

from __future__ import annotations

import numpy as np

from amrst.review.manual_keep import judge_refinement
from amrst.stages.coarse import CoarseParams
from amrst.types import make_transform


def _rz(deg: float) -> np.ndarray:
    a = np.radians(deg)
    return np.array([[np.cos(a), -np.sin(a), 0], [np.sin(a), np.cos(a), 0], [0, 0, 1]])


def test_a_refinement_that_leaves_the_solution_is_dropped_and_a_small_one_kept():
    rng = np.random.default_rng(0)
    target = rng.uniform([-2, -2, 0], [2, 2, 8], (4000, 3))
    source = target.copy()  # the identity is the truth
    T_manual = make_transform(_rz(0.3), np.array([0.01, 0.0, 0.0]))
    small = judge_refinement(T_manual, np.eye(4), target, source, CoarseParams())
    assert not small.keep_manual
    assert small.score_refined >= small.score_manual
    assert "refined your manual pose" in small.why
    far = make_transform(_rz(12.0), np.array([0.3, 0.0, 0.0]))
    slid = judge_refinement(T_manual, far, target, source, CoarseParams())
    assert slid.keep_manual
    assert slid.turn_deg > 11
    assert "your pose is kept" in slid.why


def test_fine_s_result_gives_way_to_the_manual_pose_it_would_spoil():
    from amrst.review.manual_keep import keep_manual
    from amrst.stages.fine import FineResult

    rng = np.random.default_rng(1)
    target = rng.uniform([-2, -2, 0], [2, 2, 8], (4000, 3))
    T_manual = make_transform(_rz(0.3), np.array([0.01, 0.0, 0.0]))
    far = make_transform(_rz(12.0), np.array([0.3, 0.0, 0.0]))
    fine = FineResult(far, "lm_icp", True, 12, 0.4, 0.02, 0.05)
    kept, decision = keep_manual(fine, T_manual, target, target, CoarseParams())
    assert decision.keep_manual
    np.testing.assert_array_equal(kept.T_target_source, T_manual)
    assert kept.method == "lm_icp (result dropped: manual pose kept)"
    near = FineResult(np.eye(4), "lm_icp", True, 12, 0.9, 0.01, 0.05)
    same, decision = keep_manual(near, T_manual, target, target, CoarseParams())
    assert not decision.keep_manual
    assert same is near
