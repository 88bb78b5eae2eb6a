"""Trunk heading search: trunk centre, levelled polish, the sweep, and the pipeline's
fallback when no tetrahedron match verifies."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

import amrst
from amrst.params import RegistrationParams
from amrst.stages.trunk import (
    TrunkParams,
    find_trunk_base,
    polish_levelled,
    search_yaw,
)
from amrst.types import apply_transform, make_transform


def _rot_z(deg: float) -> np.ndarray:
    a = np.radians(deg)
    return np.array([[np.cos(a), -np.sin(a), 0], [np.sin(a), np.cos(a), 0], [0, 0, 1]])


def _half_trunk(rng, centre_xy, radius, facing_deg, height=3.0, n=3000):
    """Points on the half of a vertical cylinder that faces ``facing_deg``."""
    az = np.radians(facing_deg) + rng.uniform(-np.pi / 2, np.pi / 2, n)
    z = rng.uniform(0, height, n)
    r = radius + rng.normal(0, 0.002, n)
    return np.column_stack(
        [centre_xy[0] + r * np.cos(az), centre_xy[1] + r * np.sin(az), z]
    )


def _tree(rng, n_per_branch=800):
    """A trunk and five branches at different headings and heights (no symmetry)."""
    parts = [_half_trunk(rng, (0.0, 0.0), 0.15, 0.0, height=4.0, n=4000)]
    for heading, z0, length, rise in [
        (10, 2.0, 2.5, 0.8),
        (95, 2.6, 1.8, 1.2),
        (170, 3.0, 2.2, 0.5),
        (250, 3.4, 1.5, 1.0),
        (300, 3.8, 2.0, 0.6),
    ]:
        t = rng.uniform(0, 1, n_per_branch)
        d = np.array([np.cos(np.radians(heading)), np.sin(np.radians(heading)), 0])
        axis = t[:, None] * (length * d + [0, 0, rise]) + [0, 0, z0]
        parts.append(axis + rng.normal(0, 0.03, (n_per_branch, 3)))
    return np.vstack(parts)


def test_trunk_centre_comes_from_the_arc_not_its_centroid() -> None:
    rng = np.random.default_rng(1)
    xyz = _half_trunk(rng, (2.0, -1.0), 0.2, 45.0)
    base = find_trunk_base(xyz, TrunkParams())
    np.testing.assert_allclose(base.centre[:2], [2.0, -1.0], atol=0.01)
    assert base.radius_m == pytest.approx(0.2, abs=0.01)
    assert base.centre[2] == pytest.approx(0.0, abs=0.02)
    # The arc's centroid sits about 2r/π = 13 cm towards the scanner: the fit must not.
    assert np.linalg.norm(xyz[:, :2].mean(axis=0) - [2.0, -1.0]) > 0.1


def test_trunk_centre_falls_back_to_the_median_without_a_circle() -> None:
    rng = np.random.default_rng(2)
    flat = np.column_stack(
        [rng.uniform(-5, 5, 500), rng.normal(0, 0.001, 500), rng.uniform(0, 2, 500)]
    )  # a wall: a line in plan view fits no sensible circle
    base = find_trunk_base(flat, TrunkParams())
    assert np.isnan(base.radius_m)
    assert abs(base.centre[1]) < 0.01


def test_levelled_polish_recovers_a_small_heading_and_offset() -> None:
    from scipy.spatial import cKDTree

    rng = np.random.default_rng(3)
    tgt = _tree(rng)
    T_true = make_transform(_rot_z(4.0), np.array([0.08, -0.05, 0.03]))
    src = apply_transform(np.linalg.inv(T_true), tgt)
    T = polish_levelled(src, tgt, cKDTree(tgt), np.eye(4)[None], 0.3)[0]
    np.testing.assert_allclose(T, T_true, atol=2e-3)
    # Only a turn about the vertical: the z axis stays put.
    np.testing.assert_allclose(T[:3, 2], [0, 0, 1], atol=1e-9)


def test_heading_sweep_finds_any_heading() -> None:
    rng = np.random.default_rng(4)
    tgt = _tree(rng)
    for yaw in (37.0, 181.0, 293.0):
        T_true = make_transform(_rot_z(yaw), np.array([5.0, -3.0, 0.4]))
        # A separate draw of the same tree, in the source scanner's frame.
        src = apply_transform(np.linalg.inv(T_true), _tree(rng))
        res = search_yaw(tgt, src, TrunkParams())
        best = res.solutions[0].T_target_source
        angle = np.degrees(np.arctan2(best[1, 0], best[0, 0])) % 360
        assert min(abs(angle - yaw), 360 - abs(angle - yaw)) < 2.0, angle
        np.testing.assert_allclose(best[:3, 3], T_true[:3, 3], atol=0.15)
        assert res.solutions[0].score > 1.5 * res.solutions[1].score


def test_pipeline_falls_back_to_the_trunk_search(sample_pair) -> None:
    """With matching made impossible, the sample still registers through the trunk
    search, is marked as such, and the trunk-search candidate is verified."""
    base = RegistrationParams()
    no_match = dataclasses.replace(
        base,
        match=dataclasses.replace(
            base.match, edge_tolerance=0.005, max_residual_m=0.001, retry_relaxed=False
        ),
    )
    r = amrst.register(sample_pair.target, sample_pair.source, no_match)
    assert r.coarse.candidate.origin == "trunk"
    assert r.coarse.verified
    assert r.coarse.candidate.fine_points in ("all", "leaf")
    # Its full fine registration ran while verifying it, and is not run twice.
    assert r.fine is r.matches.refined[r.coarse.candidate.id]
    # Same transform before and after, so the metrics are measured once.
    np.testing.assert_array_equal(r.T_coarse, r.T_target_source)
    assert r.metrics_fine is r.metrics_coarse
    err = r.T_target_source @ np.linalg.inv(sample_pair.T_true)
    moved = apply_transform(err, sample_pair.target.world_xyz)
    gt = float(np.sqrt(np.mean(np.sum((moved - sample_pair.target.world_xyz) ** 2, 1))))
    assert gt < 0.05, f"gt_rmse {gt * 100:.1f} cm"
    assert "trunk" in r.timings
    # Off: the same run has nothing to offer.
    off = dataclasses.replace(no_match, trunk=TrunkParams(mode="off"))
    with pytest.raises(amrst.RegistrationFailed):
        amrst.register(sample_pair.target, sample_pair.source, off)


def test_trunk_search_does_not_run_when_a_match_verifies(sample_run) -> None:
    r = sample_run.result
    assert r.coarse.verified
    assert r.coarse.candidate.origin == "tetrahedra"
    assert "trunk" not in r.timings


def test_contenders_are_the_best_and_those_close_to_it() -> None:
    from amrst.stages.trunk_merge import trunk_contenders

    assert trunk_contenders(np.array([0.004, 0.0067, 0.002]), 0.5) == [1, 0]
    assert trunk_contenders(np.array([0.004, 0.0067, 0.002]), 1.0) == [1]
    assert trunk_contenders(np.array([0.004, 0.0067, 0.002]), 0.0) == [1, 0, 2]
    assert trunk_contenders(np.array([0.0, 0.0]), 0.5) == [0]  # nothing close at all
    assert trunk_contenders(np.array([]), 0.5) == []
    # A heading whose quick fit landed on an already picked pose is not refined again.
    same, other = np.eye(4), make_transform(np.eye(3), [1.0, 0.0, 0.0])
    close = np.array([0.004, 0.0067, 0.005])
    poses = [same, same, other]
    assert trunk_contenders(close, 0.5, poses, np.zeros(3)) == [1, 2]


def test_every_contender_gets_and_keeps_its_full_fine_fit(sample_pair) -> None:
    """With contender_share 0 every kept heading is refined in full; each of those
    fits is kept for register() to reuse, and the winner is still the right one."""
    base = RegistrationParams()
    params = dataclasses.replace(
        base,
        match=dataclasses.replace(
            base.match, edge_tolerance=0.005, max_residual_m=0.001, retry_relaxed=False
        ),
        trunk=dataclasses.replace(base.trunk, contender_share=0.0),
    )
    r = amrst.register(sample_pair.target, sample_pair.source, params)
    trunk = [c for c in r.matches.candidates if c.origin == "trunk"]
    assert len(trunk) >= 2
    # Every distinct heading was refined in full (same-pose ones once).
    assert set(r.matches.refined) <= {c.id for c in trunk}
    assert len(r.matches.refined) >= 2
    assert r.fine is r.matches.refined[r.coarse.candidate.id]
    err = r.T_target_source @ np.linalg.inv(sample_pair.T_true)
    moved = apply_transform(err, sample_pair.target.world_xyz)
    assert (
        float(np.sqrt(np.mean(np.sum((moved - sample_pair.target.world_xyz) ** 2, 1))))
        < 0.05
    )
