"""Closed-form covariance features agree with numpy's eigh (brute force)."""

import numpy as np
from scipy.spatial import cKDTree

from amrst.stages.features import otsu_threshold, shape_features


def every_point(xyz: np.ndarray, k: int) -> dict[str, np.ndarray]:
    """shape_features at one scale on every point, from its own neighbour query."""
    return shape_features(xyz, cKDTree(xyz).query(xyz, k=k)[1], (k,))[0]


def test_shape_features_match_eigh() -> None:
    rng = np.random.default_rng(0)
    xyz = rng.normal(size=(3000, 3)) * [3.0, 1.0, 0.2]
    got = every_point(xyz, 20)
    idx = cKDTree(xyz).query(xyz, k=20)[1]
    nb = xyz[idx] - xyz[idx].mean(axis=1, keepdims=True)
    w = np.linalg.eigvalsh(np.einsum("nki,nkj->nij", nb, nb) / 20)
    w = np.clip(w, 1e-12, None)
    np.testing.assert_allclose(
        got["linearity"], (w[:, 2] - w[:, 1]) / w[:, 2], atol=1e-9
    )
    np.testing.assert_allclose(
        got["planarity"], (w[:, 1] - w[:, 0]) / w[:, 2], atol=1e-9
    )
    np.testing.assert_allclose(got["scattering"], w[:, 0] / w[:, 2], atol=1e-9)
    np.testing.assert_allclose(got["curvature"], w[:, 0] / w.sum(axis=1), atol=1e-9)


def test_line_is_recognised() -> None:
    t = np.linspace(0, 10, 500)
    line = np.column_stack([t, 0 * t, 0 * t]) + 1e-4 * np.random.default_rng(1).normal(
        size=(500, 3)
    )
    assert np.median(every_point(line, 10)["linearity"]) > 0.99


def test_otsu_splits_two_modes() -> None:
    rng = np.random.default_rng(2)
    values = np.r_[rng.normal(0.0, 0.1, 1000), rng.normal(1.0, 0.1, 1000)]
    assert 0.3 < otsu_threshold(values) < 0.7


def test_several_scales_on_some_rows_equal_one_scale_on_every_point() -> None:
    """Several scales from one neighbour list, on a subset of rows, equal one call
    per scale on all points."""
    rng = np.random.default_rng(3)
    xyz = rng.normal(size=(2000, 3)) * [2.0, 1.0, 0.1] + [500.0, -300.0, 40.0]
    nb = cKDTree(xyz).query(xyz, k=30)[1]
    rows = np.arange(0, 2000, 7)
    got = shape_features(xyz, nb[rows], (30, 10))
    for feats, k in zip(got, (30, 10), strict=True):
        want = every_point(xyz, k)
        assert set(feats) == {"linearity", "planarity", "scattering", "curvature"}
        for name, value in feats.items():
            np.testing.assert_allclose(value, want[name][rows], atol=1e-9)
