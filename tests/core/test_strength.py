"""Strength per axis: free motions of a shape read as weak, held ones as strong."""

from __future__ import annotations

import numpy as np

from amrst.review.strength import AXES, WEAK_STRENGTH, axis_strength


def _cylinder(n: int = 20_000, seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    a = rng.uniform(0, 2 * np.pi, n)
    z = rng.uniform(0, 3, n)
    return np.c_[0.2 * np.cos(a), 0.2 * np.sin(a), z] + rng.normal(0, 0.001, (n, 3))


def test_a_bare_stem_does_not_hold_its_turn_about_the_axis() -> None:
    stem = _cylinder()
    s = axis_strength(stem, stem, np.eye(4), 0.05)
    assert set(s.values) == set(AXES)
    assert s.values["rz"] < WEAK_STRENGTH
    assert s.values["tx"] > 0.5
    assert s.values["ty"] > 0.5
    assert s.weak[0] == "rz"
    assert "rotation about the stem" in s.advice()


def test_a_flat_ground_does_not_hold_sideways_shifts() -> None:
    rng = np.random.default_rng(1)
    ground = np.c_[rng.uniform(-5, 5, (20_000, 2)), rng.normal(0, 0.001, 20_000)]
    s = axis_strength(ground, ground, np.eye(4), 0.05)
    assert s.values["tz"] > 0.9
    assert {"tx", "ty", "rz"} <= set(s.weak)
    assert "rx" not in s.weak
    assert "ry" not in s.weak


def test_a_stem_with_a_branch_holds_every_axis() -> None:
    stem = _cylinder()
    rng = np.random.default_rng(2)
    t = rng.uniform(0, 1.5, 5000)
    branch = np.c_[t, np.zeros_like(t), 1.5 + 0.3 * t] + rng.normal(0, 0.03, (5000, 3))
    tree = np.vstack([stem, branch])
    s = axis_strength(tree, tree, np.eye(4), 0.05)
    assert s.weak == ()
    assert s.advice() == ""


def test_the_pose_moves_the_source_before_the_overlap_is_found() -> None:
    stem = _cylinder()
    T = np.eye(4)
    T[:3, 3] = (5.0, 0.0, 0.0)
    apart = axis_strength(stem, stem, T, 0.05)
    assert apart.n_points == 0
    assert all(np.isnan(v) for v in apart.values.values())
    moved_back = stem - T[:3, 3]
    assert axis_strength(stem, moved_back, T, 0.05).n_points > 10_000


def test_too_few_points_give_nan_not_an_error() -> None:
    s = axis_strength(np.zeros((3, 3)), np.zeros((1, 3)), np.eye(4), 0.05)
    assert s.n_points == 0
    assert all(np.isnan(v) for v in s.values.values())
