"""Metrics against brute force (full distance matrices) and known rotations."""

from __future__ import annotations

import numpy as np
import pytest

from amrst.stages.metrics import (
    CloudMetrics,
    MetricsParams,
    TruthErrors,
    measure_clouds,
    truth_errors,
)
from amrst.types import apply_transform, make_transform


def _rot(axis, angle_deg: float) -> np.ndarray:
    from scipy.spatial.transform import Rotation

    axis = np.asarray(axis, dtype=float)
    return Rotation.from_rotvec(
        np.radians(angle_deg) * axis / np.linalg.norm(axis)
    ).as_matrix()


@pytest.fixture
def clouds() -> tuple[np.ndarray, np.ndarray]:
    """200 target points; 200 source points, half near the target, half 0.3-1 m away."""
    rng = np.random.default_rng(4)
    target = rng.uniform(0, 2, (200, 3))
    near = target[:100] + rng.normal(0, 0.02, (100, 3))
    far = rng.uniform(0, 2, (100, 3)) + np.array([0, 0, rng.uniform(0.3, 1.0)])
    return target, np.vstack([near, far])


def test_measure_clouds_agrees_with_brute_force(clouds) -> None:
    target, source = clouds
    params = MetricsParams(overlap_dist_m=0.05)
    m = measure_clouds(target, source, params)
    # Full distance matrix, source rows x target columns.
    D = np.sqrt(((source[:, None, :] - target[None, :, :]) ** 2).sum(axis=2))
    d_st, d_ts = D.min(axis=1), D.min(axis=0)
    inside = d_st < 0.05
    assert 0 < inside.sum() < len(source)  # the test covers both cases
    assert isinstance(m, CloudMetrics)
    assert m.rmse_m == pytest.approx(np.sqrt(np.mean(d_st**2)), rel=1e-12)
    assert m.rmse_overlap_m == pytest.approx(
        np.sqrt(np.mean(d_st[inside] ** 2)), rel=1e-12
    )
    assert m.hausdorff_m == pytest.approx(max(d_st.max(), d_ts.max()), rel=1e-12)
    assert m.hausdorff_p95_m == pytest.approx(
        np.percentile(np.r_[d_st, d_ts], 95), rel=1e-12
    )
    assert m.overlap_fraction == pytest.approx(inside.mean())
    assert (m.n_target, m.n_source) == (200, 200)
    d = m.as_dict()
    assert d["rmse_m"] == m.rmse_m
    assert set(d) == {
        "rmse_m",
        "rmse_overlap_m",
        "hausdorff_m",
        "hausdorff_p95_m",
        "overlap_fraction",
        "n_target",
        "n_source",
    }


def test_hausdorff_is_symmetric_and_sees_the_target_side(clouds) -> None:
    """A target point far from every source point sets the Hausdorff distance."""
    target, source = clouds
    target = np.vstack([target, [[10.0, 0.0, 0.0]]])
    m = measure_clouds(target, source)
    D = np.sqrt(((source[:, None, :] - target[None, :, :]) ** 2).sum(axis=2))
    assert m.hausdorff_m == pytest.approx(D[:, -1].min())
    assert m.hausdorff_m > 8.0
    assert m.rmse_m < 1.0  # source -> target distances do not see it


def test_identical_clouds_measure_zero(clouds) -> None:
    target, _ = clouds
    m = measure_clouds(target, target.copy())
    assert m.rmse_m == 0.0
    assert m.hausdorff_m == 0.0
    assert m.overlap_fraction == 1.0


def test_no_overlap_gives_nan_overlap_rmse(clouds) -> None:
    target, _ = clouds
    m = measure_clouds(target, target + np.array([100.0, 0, 0]))
    assert m.overlap_fraction == 0.0
    assert np.isnan(m.rmse_overlap_m)
    assert m.rmse_m == pytest.approx(100.0, rel=0.05)


def test_sampling_limits_the_points_but_reports_the_sizes() -> None:
    rng = np.random.default_rng(0)
    target = rng.uniform(0, 1, (3000, 3))
    m = measure_clouds(target, target.copy(), MetricsParams(max_points=500))
    assert (m.n_target, m.n_source) == (3000, 3000)
    assert 0.0 < m.rmse_m < 0.2  # two independent samples of one cloud
    again = measure_clouds(target, target.copy(), MetricsParams(max_points=500))
    assert again == m  # seeded


def test_truth_errors_of_a_known_rotation() -> None:
    rng = np.random.default_rng(1)
    src = rng.uniform(-5, 5, (200, 3))
    T_true = make_transform(_rot([0.2, -0.4, 1.0], 30.0), [1.0, 2.0, 3.0])
    T_est = make_transform(_rot([1.0, 1.0, 0.0], 3.0), [0.0, 0.0, 0.0]) @ T_true
    e = truth_errors(T_est, T_true, src)
    assert isinstance(e, TruthErrors)
    assert e.rotation_error_deg == pytest.approx(3.0, abs=1e-9)
    assert e.translation_error_m == pytest.approx(
        np.linalg.norm(T_est[:3, 3] - T_true[:3, 3])
    )
    diff = apply_transform(T_est, src) - apply_transform(T_true, src)
    assert e.gt_rmse_m == pytest.approx(
        np.sqrt(np.mean(np.sum(diff**2, axis=1))), rel=1e-12
    )
    assert e.gt_rmse_m > 0.1
    assert not e.registered()
    assert e.as_dict()["rotation_error_deg"] == e.rotation_error_deg


def test_truth_errors_of_the_truth_are_zero() -> None:
    src = np.random.default_rng(2).uniform(-5, 5, (100, 3))
    T_true = make_transform(_rot([0, 0, 1], 70.0), [3.0, -2.0, 0.5])
    # R R^T of a 70 deg rotation is the identity only to rounding: arccos of the
    # trace leaves about 1e-6 deg; an exact identity gives exactly 0.
    assert truth_errors(np.eye(4), np.eye(4), src).rotation_error_deg == 0.0
    e = truth_errors(T_true.copy(), T_true, src)
    assert e.rotation_error_deg == pytest.approx(0.0, abs=1e-5)
    assert e.translation_error_m == 0.0
    assert e.gt_rmse_m == 0.0
    assert e.registered()


def test_translation_error_and_success_rule() -> None:
    src = np.zeros((10, 3))
    T_true = np.eye(4)
    e = truth_errors(make_transform(np.eye(3), [0.03, 0.0, 0.04]), T_true, src)
    assert e.translation_error_m == pytest.approx(0.05)
    assert e.gt_rmse_m == pytest.approx(0.05)
    off = truth_errors(make_transform(np.eye(3), [0.0, 0.06, 0.0]), T_true, src)
    assert not off.registered()  # gt_rmse must be below 5 cm
    assert off.registered(max_gt_rmse_m=0.07)
    near = truth_errors(make_transform(np.eye(3), [0.0, 0.04, 0.0]), T_true, src)
    assert near.registered()
    tilted = truth_errors(make_transform(_rot([1, 0, 0], 1.5), [0, 0, 0]), T_true, src)
    assert tilted.gt_rmse_m == 0.0  # all points at the origin
    assert not tilted.registered()  # rotation must be below 1 deg


def test_params_are_validated() -> None:
    with pytest.raises(ValueError, match="overlap_dist_m"):
        MetricsParams(overlap_dist_m=0.0)
    with pytest.raises(ValueError, match="max_points"):
        MetricsParams(max_points=0)
