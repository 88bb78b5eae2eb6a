"""A refinement of a manual pose replaces it only when it stays the same solution."""

from __future__ import annotations

import numpy as np

from amrst.manual_keep import judge_refinement
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
