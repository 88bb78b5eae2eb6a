"""The whole chain on the bundled sample pair: truth, determinism, world frames,
progress and cancel, and the step-by-step API the app uses."""

from __future__ import annotations

import dataclasses
import itertools

import numpy as np
import pytest

import amrst
from amrst.errors import Cancelled, RegistrationFailed
from amrst.pipeline import (
    RegistrationParams,
    coarse_from_matches,
    evaluate,
    find_matches,
    refine,
)
from amrst.progress import EventReporter
from amrst.stages.keypoints import KeypointResult
from amrst.types import (
    Cloud,
    apply_transform,
    local_transform,
    make_transform,
    world_transform,
)


def _rot_err_deg(Ra: np.ndarray, Rb: np.ndarray) -> float:
    from scipy.spatial.transform import Rotation

    return float(np.degrees(Rotation.from_matrix(Ra @ Rb.T).magnitude()))


def _gt_rmse(T: np.ndarray, T_true: np.ndarray, xyz: np.ndarray) -> float:
    d = apply_transform(T, xyz) - apply_transform(T_true, xyz)
    return float(np.sqrt(np.mean(np.sum(d**2, axis=1))))


def test_register_recovers_the_sample_truth(sample_pair, sample_run) -> None:
    r = sample_run.result
    rot = _rot_err_deg(r.T_target_source[:3, :3], sample_pair.T_true[:3, :3])
    gt = _gt_rmse(r.T_target_source, sample_pair.T_true, sample_pair.source.world_xyz)
    assert rot < 1.0, f"rotation error {rot:.3f} deg"
    assert gt < 0.05, f"gt_rmse {gt * 100:.1f} cm"


def test_register_coarse_solution_is_near_the_truth(sample_pair, sample_run) -> None:
    r = sample_run.result
    rot = _rot_err_deg(r.T_coarse[:3, :3], sample_pair.T_true[:3, :3])
    gt = _gt_rmse(r.T_coarse, sample_pair.T_true, sample_pair.source.world_xyz)
    assert rot < 2.0
    assert gt < 0.3


def test_register_result_is_complete(sample_pair, sample_run) -> None:
    r = sample_run.result
    assert isinstance(r, amrst.RegistrationResult)
    assert r.T_target_source.shape == (4, 4)
    np.testing.assert_allclose(r.T_target_source[3], [0, 0, 0, 1])
    assert np.linalg.det(r.T_target_source[:3, :3]) == pytest.approx(1.0)
    assert 0.0 <= r.confidence <= 1.0
    assert r.message == r.coarse.message
    assert r.params == RegistrationParams()
    assert {
        "preprocess",
        "separate",
        "skeleton",
        "keypoints",
        "match",
        "verify",
    } <= set(r.timings)
    assert {"fine", "metrics", "total"} <= set(r.timings)
    assert r.timings["total"] >= r.timings["fine"] > 0
    for scan, cloud in ((r.target, sample_pair.target), (r.source, sample_pair.source)):
        assert scan.cloud is cloud
        assert len(scan.keypoints.xyz) >= 4
        assert scan.pre.index.max() < len(cloud)
        np.testing.assert_array_equal(scan.xyz, cloud.xyz[scan.pre.index])
    assert r.metrics_fine.n_source == len(r.source.xyz)
    assert r.fine.fitness > 0


def test_step_by_step_api_reproduces_register(sample_run) -> None:
    """coarse_from_matches, refine and evaluate give what register() stored."""
    r = sample_run.result
    params = r.params
    coarse = coarse_from_matches(r.matches)
    assert coarse.candidate.id == r.coarse.candidate.id
    np.testing.assert_array_equal(coarse.T_target_source, r.coarse.T_target_source)
    fine = refine(r.target, r.source, coarse.T_target_source, params)
    np.testing.assert_allclose(fine.T_target_source, r.fine.T_target_source, atol=1e-9)
    m = evaluate(r.target, r.source, r.fine.T_target_source, params)
    assert m == r.metrics_fine
    # Offsets are zero here: world and local transforms coincide.
    np.testing.assert_allclose(r.T_target_source, r.fine.T_target_source, atol=1e-12)


def test_progress_is_monotonic_and_ends_at_one(sample_run) -> None:
    fractions = [f for f, _ in sample_run.progress]
    assert len(fractions) > 10
    assert all(0.0 <= f <= 1.0 for f in fractions)
    assert all(b >= a - 1e-12 for a, b in itertools.pairwise(fractions))
    assert sample_run.progress[-1] == (1.0, "done")
    assert all(isinstance(m, str) for _, m in sample_run.progress)


@pytest.mark.slow
def test_register_is_deterministic(sample_pair, sample_run) -> None:
    first = sample_run.result
    again = amrst.register(sample_pair.target, sample_pair.source)
    np.testing.assert_array_equal(
        again.source.keypoints.xyz, first.source.keypoints.xyz
    )
    np.testing.assert_array_equal(
        again.matches.tetra.T_target_source, first.matches.tetra.T_target_source
    )
    assert [c.id for c in again.matches.candidates] == [
        c.id for c in first.matches.candidates
    ]
    np.testing.assert_array_equal(again.T_coarse, first.T_coarse)
    # Bit for bit with the default lm_icp. (fine.method="robust_plane" goes through
    # Open3D's multithreaded sums, which differ by ~1e-14 from run to run.)
    np.testing.assert_array_equal(again.T_target_source, first.T_target_source)


def test_world_transform_composes_the_offsets() -> None:
    rng = np.random.default_rng(0)
    o_t = np.array([500000.0, 5000000.0, 100.0])
    o_s = np.array([500020.0, 4999990.0, 101.0])
    target = Cloud(rng.uniform(0, 5, (10, 3)), o_t)
    source = Cloud(rng.uniform(0, 5, (10, 3)), o_s)
    from scipy.spatial.transform import Rotation

    T_local = make_transform(
        Rotation.from_euler("z", 30, degrees=True).as_matrix(), [1, 2, 3]
    )
    T_world = world_transform(T_local, target, source)
    # A source point: local x, world x + o_s. Its image: local T_local x in the target
    # frame, world T_local x + o_t.
    x = source.xyz
    mapped_world = apply_transform(T_world, x + o_s)
    np.testing.assert_allclose(
        mapped_world - o_t, apply_transform(T_local, x), atol=1e-6
    )
    np.testing.assert_allclose(
        local_transform(T_world, target, source), T_local, atol=1e-9
    )
    np.testing.assert_array_equal(T_world[:3, :3], T_local[:3, :3])


@pytest.mark.slow
def test_large_offset_registers_to_the_same_world_transform(
    sample_pair, sample_run
) -> None:
    """Both scans moved to x = 500000, y = 5000000 and split into offset + local the way
    the readers do (each cloud its own offset, rounded down to whole kilometres)."""
    o = np.array([500000.0, 5000000.0, 100.0])

    def georeferenced(cloud: Cloud) -> Cloud:
        world = cloud.xyz + o
        offset = np.floor(world.min(axis=0) / 1000.0) * 1000.0
        return Cloud(world - offset, offset)

    target, source = (
        georeferenced(sample_pair.target),
        georeferenced(sample_pair.source),
    )
    assert not np.array_equal(target.offset, source.offset)
    shifted = amrst.register(target, source)
    T0, T2 = sample_run.result.T_target_source, shifted.T_target_source
    # T2 must be S(o) T0 S(-o): compare where both send the source points, without
    # forming the large coordinates: T2 (x + o) - o  vs  T0 x.
    x = sample_pair.source.xyz
    moved2 = x @ T2[:3, :3].T + (T2[:3, :3] @ o + T2[:3, 3] - o)
    moved0 = apply_transform(T0, x)
    assert np.abs(moved2 - moved0).max() < 1e-3
    assert _rot_err_deg(T2[:3, :3], T0[:3, :3]) < 0.01


def test_cancel_stops_register(sample_pair) -> None:
    reporter = EventReporter()
    reporter.cancel()
    with pytest.raises(Cancelled):
        amrst.register(sample_pair.target, sample_pair.source, reporter=reporter)


def test_find_matches_needs_four_key_points(sample_run) -> None:
    r = sample_run.result
    kp = r.source.keypoints
    three = KeypointResult(
        kp.xyz[:3], kp.kind[:3], kp.weight[:3], kp.node[:3], kp.depth[:3]
    )
    few = dataclasses.replace(r.source, keypoints=three)
    no_trunk = dataclasses.replace(
        r.params, trunk=dataclasses.replace(r.params.trunk, mode="off")
    )
    with pytest.raises(
        RegistrationFailed, match="source skeleton has only 3 key points"
    ):
        find_matches(r.target, few, no_trunk)
    # With the trunk heading search (the default) there is still something to offer.
    trunk_only = dataclasses.replace(
        r.params, global_match=dataclasses.replace(r.params.global_match, mode="off")
    )
    m = find_matches(r.target, few, trunk_only)
    assert m.n_matches == 0
    assert m.candidates
    assert all(c.origin == "trunk" for c in m.candidates)
    assert coarse_from_matches(m).verified
    bare = dataclasses.replace(r.target, skeleton=None, keypoints=None)
    with pytest.raises(RegistrationFailed, match="key points of both scans first"):
        find_matches(bare, r.source, r.params)


def test_sample_registration_is_verified(sample_run) -> None:
    coarse = sample_run.result.coarse
    assert coarse.verified
    assert coarse.candidate.polished
    assert coarse.confidence > 0.3
