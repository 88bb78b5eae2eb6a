"""Baselines: each recovers a known small offset on the tiny tree; shared helpers."""

from __future__ import annotations

from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from amrst.baselines import METHODS, MethodResult, NdtParams, register_ndt
from amrst.baselines._common import evaluate, to_local, to_world, voxel_down
from amrst.stages.metrics import truth_errors
from amrst.types import Cloud, apply_transform, invert_transform, make_transform

TINY = Path(__file__).resolve().parents[1] / "data" / "tiny_tree" / "tree.ply"


def _rotation(axis, angle_deg: float) -> np.ndarray:
    from scipy.spatial.transform import Rotation

    axis = np.asarray(axis, dtype=float)
    rotvec = np.radians(angle_deg) * axis / np.linalg.norm(axis)
    return Rotation.from_rotvec(rotvec).as_matrix()


def _pair(angle_deg: float, shift_m: float, offset=(0.0, 0.0, 0.0), seed: int = 0):
    """Target = tiny tree; source = the same points moved by the inverse of a known
    ``T_target_source`` plus 2 mm noise."""
    from amrst import io

    tree = io.read(TINY)
    rng = np.random.default_rng(seed)
    direction = rng.normal(size=3)
    T_true = make_transform(
        _rotation(rng.normal(size=3), angle_deg),
        shift_m * direction / np.linalg.norm(direction),
    )
    src_xyz = apply_transform(invert_transform(T_true), tree.xyz)
    src_xyz = src_xyz + rng.normal(0.0, 0.002, src_xyz.shape)
    offset = np.asarray(offset, dtype=float)
    target = Cloud(tree.xyz, offset)
    # Both clouds live at the same world offset; the truth is the world transform.
    source = Cloud(src_xyz, offset)
    T_world = to_world(T_true, offset)
    return target, source, T_world


def _check(result: MethodResult, source: Cloud, T_true, rot_deg=0.3, gt_m=0.02):
    assert set(result.timings) >= {"total"}
    assert result.T_target_source.shape == (4, 4)
    err = truth_errors(
        to_local(result.T_target_source, source.offset),
        to_local(T_true, source.offset),
        source.xyz,
    )
    assert err.rotation_error_deg < rot_deg, err
    assert err.gt_rmse_m < gt_m, err


def test_registry_names() -> None:
    assert set(METHODS) == {
        "icp",
        "icp_centroid",
        "ndt",
        "fpfh_ransac",
        "fgr",
        "kiss_matcher",
        "kiss_gicp",
        "amrst",
    }


@pytest.mark.parametrize("name", ["icp", "icp_centroid", "fpfh_ransac", "fgr"])
def test_open3d_methods_recover_a_small_offset(name: str) -> None:
    target, source, T_true = _pair(3.0, 0.2)
    result = METHODS[name](target, source)
    _check(result, source, T_true)
    assert result.fitness > 0.9


@pytest.mark.parametrize("name", ["fpfh_ransac", "fgr"])
def test_feature_methods_refuse_a_cloud_of_one_spot(name: str) -> None:
    from amrst.errors import InvalidInput

    target, _source, _T = _pair(3.0, 0.2)
    spot = Cloud(np.full((5000, 3), 1.5))  # 5,000 copies of one point
    with pytest.raises(InvalidInput, match=r"^The source scan fills 1 voxel\(s\)"):
        METHODS[name](target, spot)


def test_icp_keeps_georeferenced_precision() -> None:
    target, source, T_true = _pair(3.0, 0.2, offset=(500_000.0, 5_000_000.0, 300.0))
    _check(METHODS["icp"](target, source), source, T_true)


def test_ndt_converges_from_5_deg_30_cm() -> None:
    for seed in (1, 2):
        target, source, T_true = _pair(5.0, 0.3, seed=seed)
        result = METHODS["ndt"](target, source)
        _check(result, source, T_true)
        assert result.iterations is not None
        assert result.iterations > 0
        assert result.timings["total"] < 20.0


def test_ndt_accepts_an_initial_transform() -> None:
    target, source, T_true = _pair(30.0, 2.0, seed=3)
    near = T_true @ make_transform(_rotation([0, 0, 1], 1.0), [0.05, 0.0, 0.0])
    params = NdtParams(cell_sizes_m=(1.0, 0.5))
    _check(register_ndt(target, source, params, T_init=near), source, T_true)


def test_ndt_respects_its_time_budget() -> None:
    target, source, _ = _pair(5.0, 0.3)
    params = NdtParams(max_seconds=0.0)
    result = register_ndt(target, source, params)
    assert result.converged is False
    assert result.iterations <= 1


def test_ndt_gradient_and_hessian_match_finite_differences() -> None:
    from amrst.baselines.ndt import NdtGrid, _Scorer, build_grid
    from amrst.geometry import rotvec_matrix

    rng = np.random.default_rng(0)
    tgt = rng.normal(size=(3000, 3)) * [3.0, 2.0, 1.0]
    grid = build_grid(tgt, 4.0, 5, 0.55)
    # A huge search radius keeps the scored cells fixed, so the score is smooth.
    wide = NdtGrid(1e9, grid.means, grid.inv_covs, grid.d1, grid.d2)
    scorer = _Scorer(wide, len(grid.means))
    src = tgt[:300] + rng.normal(0, 0.05, (300, 3)) + [0.1, 0.05, 0.0]
    c = src.mean(axis=0)

    def f(p):
        return scorer.score((src - c) @ rotvec_matrix(p[:3]).T + c + p[3:])

    _, grad, hess = scorer.derivatives(src, c)
    h, eye = 1e-4, np.eye(6)
    num_grad = [(f(h * eye[i]) - f(-h * eye[i])) / (2 * h) for i in range(6)]
    np.testing.assert_allclose(grad, num_grad, rtol=1e-4, atol=1e-4)
    num_hess = np.array(
        [
            [
                (
                    f(h * (eye[i] + eye[j]))
                    - f(h * (eye[i] - eye[j]))
                    - f(h * (eye[j] - eye[i]))
                    + f(-h * (eye[i] + eye[j]))
                )
                / (4 * h * h)
                for j in range(6)
            ]
            for i in range(6)
        ]
    )
    np.testing.assert_allclose(hess, num_hess, rtol=1e-3, atol=1e-2)


def test_frames_round_trip_and_evaluate() -> None:
    T = make_transform(_rotation([1, 2, 3], 20.0), [1.0, 2.0, 3.0])
    origin = np.array([500_000.0, 5_000_000.0, 100.0])
    np.testing.assert_allclose(to_local(to_world(T, origin), origin), T, atol=1e-6)
    xyz = np.random.default_rng(0).uniform(0, 2, (2000, 3))
    assert len(voxel_down(xyz, 0.5)) <= 64
    fitness, rmse = evaluate(xyz, xyz, np.eye(4))
    assert fitness == 1.0
    assert rmse < 0.05


def test_amrst_method_wraps_the_engine(monkeypatch) -> None:
    import amrst

    target, source, T_true = _pair(3.0, 0.2)
    fake = SimpleNamespace(
        T_target_source=T_true,
        confidence=0.8,
        timings={"coarse": 0.1, "metrics": 0.05, "total": 0.2},
        coarse=SimpleNamespace(
            verified=True, candidate=SimpleNamespace(origins=("tetrahedra", "features"))
        ),
    )
    monkeypatch.setattr(amrst, "register", lambda t, s: fake)
    result = METHODS["amrst"](target, source)
    np.testing.assert_allclose(result.T_target_source, T_true)
    assert result.extra["confidence"] == 0.8
    assert result.extra["verified"] is True
    assert result.extra["origin"] == "tetrahedra+features"
    # Like the baselines' own fitness evaluation, the metrics stage is not timed.
    assert result.timings["total"] == pytest.approx(0.15)
    assert result.timings["total_with_metrics"] == 0.2
    assert result.fitness > 0.9
