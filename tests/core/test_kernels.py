"""Fast kernels against slow reference answers (reference code kept here, or brute force)."""

from __future__ import annotations

import numpy as np
import pytest

from amrst.stages.voxels import sorted_unique, voxel_grid, voxel_representatives


def _reference_representatives(
    xyz: np.ndarray, voxel: float
) -> tuple[np.ndarray, np.ndarray]:
    """The stable-sort implementation voxel_representatives had before (kept verbatim)."""
    code = voxel_grid(xyz, voxel)[1]
    order = np.argsort(code, kind="stable")
    sorted_code = code[order]
    new = np.empty(len(order), dtype=bool)
    new[0] = True
    np.not_equal(sorted_code[1:], sorted_code[:-1], out=new[1:])
    group = np.cumsum(new) - 1
    n = int(group[-1]) + 1
    pts = xyz[order]
    counts = np.bincount(group, minlength=n)
    centroids = np.column_stack([np.bincount(group, pts[:, d], n) for d in range(3)])
    dist = np.sum((pts - centroids[group] / counts[group, None]) ** 2, axis=1)
    nearest = np.minimum.reduceat(dist, np.flatnonzero(new))
    hit = np.flatnonzero(dist == nearest[group])
    first = np.empty(len(hit), dtype=bool)
    first[0] = True
    np.not_equal(group[hit][1:], group[hit][:-1], out=first[1:])
    rep_of_group = order[hit[first]]
    by_index = np.argsort(rep_of_group)
    reps = rep_of_group[by_index]
    rank = np.empty(n, dtype=np.int64)
    rank[by_index] = np.arange(n)
    owner = np.empty(len(xyz), dtype=np.int64)
    owner[order] = rank[group]
    return reps, owner


@pytest.mark.parametrize("voxel", [0.01, 0.05, 0.3])
def test_voxel_representatives_equal_the_stable_sort_version(voxel: float) -> None:
    """Identical indices and owners, ties (exact duplicates, two-point voxels) included."""
    rng = np.random.default_rng(11)
    xyz = rng.normal(size=(40_000, 3)) * [1.0, 1.0, 4.0]
    xyz = np.vstack([xyz, xyz[:3000], xyz[:500]])  # duplicates, some tripled
    xyz = xyz[rng.permutation(len(xyz))]
    reps, owner = voxel_representatives(xyz, voxel)
    ref_reps, ref_owner = _reference_representatives(xyz, voxel)
    np.testing.assert_array_equal(reps, ref_reps)
    np.testing.assert_array_equal(owner, ref_owner)


@pytest.mark.parametrize("n", [0, 1, 2, 1000])
def test_sorted_unique_equals_numpy_unique(n: int) -> None:
    rng = np.random.default_rng(n)
    codes = rng.integers(-(1 << 62), 1 << 62, size=n)
    codes = np.concatenate([codes, codes[: n // 3], rng.integers(0, 5, size=n)])
    np.testing.assert_array_equal(sorted_unique(codes), np.unique(codes))
    assert sorted_unique(codes).dtype == codes.dtype


def test_voxel_grid_codes_separate_voxels_on_a_huge_grid() -> None:
    """More than 2^21 voxels along an axis: the row-wise fallback still groups right."""
    xyz = np.array([[0.0, 0, 0], [0.0005, 0, 0], [5000.0, 0, 0], [5000.0004, 0, 0]])
    keys, code = voxel_grid(xyz, 0.001)
    assert keys[:, 0].max() >= 1 << 21
    assert code[0] == code[1] != code[2] == code[3]
    reps, owner = voxel_representatives(xyz, 0.001)
    assert len(reps) == 2
    np.testing.assert_array_equal(owner, [0, 0, 1, 1])


def _cloud_with_duplicates(n: int, seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    xyz = rng.normal(size=(n, 3)) * [1.0, 1.0, 3.0]
    xyz = np.vstack([xyz, xyz[: n // 10], xyz[: n // 50]])  # doubled and tripled points
    return xyz[rng.permutation(len(xyz))]


def _same_neighbours(
    d: np.ndarray,
    i: np.ndarray,
    d_ref: np.ndarray,
    i_ref: np.ndarray,
    xyz: np.ndarray,
    q: np.ndarray,
) -> None:
    """A valid k-nearest answer: scipy's distances, each index really at its distance,
    no index twice in a row. Equidistant neighbours (duplicates) may come in another
    order or, at the k-th place, be another of the tied points."""
    np.testing.assert_allclose(d, d_ref, rtol=1e-12, atol=1e-12)
    found = np.isfinite(d_ref)
    np.testing.assert_array_equal(np.isfinite(d), found)
    np.testing.assert_array_equal(i[~found], i_ref[~found])
    rows, cols = np.nonzero(found)
    at = np.linalg.norm(xyz[i[rows, cols]] - q[rows], axis=1)
    np.testing.assert_allclose(at, d[rows, cols], rtol=1e-9, atol=1e-12)
    srt = np.sort(np.where(found, i, -1 - np.arange(i.shape[1])), axis=1)
    assert np.all(np.diff(srt, axis=1) != 0)


@pytest.mark.parametrize("k", [1, 2, 13, 30])
def test_knn_equals_scipy_ckdtree(k: int) -> None:
    from scipy.spatial import cKDTree

    from amrst.neighbours import knn

    xyz = _cloud_with_duplicates(20_000, seed=k)
    queries = np.vstack([xyz[::7], np.random.default_rng(1).normal(size=(500, 3))])
    for q in (None, queries):
        d, i = knn(xyz, k, q)
        qq = xyz if q is None else q
        d_ref, i_ref = cKDTree(xyz).query(qq, k=k)
        assert i.dtype == np.int64
        _same_neighbours(d, i, d_ref.reshape(d.shape), i_ref.reshape(i.shape), xyz, qq)


def test_knn_refuses_an_impossible_k() -> None:
    from amrst.neighbours import knn

    with pytest.raises(ValueError, match="k must be"):
        knn(np.zeros((5, 3)), 6)


@pytest.mark.parametrize(
    ("k", "bound"), [(1, np.inf), (1, 0.05), (2, 0.1), (3, np.inf)]
)
def test_nearest_tree_equals_scipy_ckdtree(k: int, bound: float) -> None:
    from scipy.spatial import cKDTree

    from amrst.neighbours import NearestTree

    xyz = _cloud_with_duplicates(10_000, seed=3)
    q = np.vstack([xyz[::5] + 0.01, np.random.default_rng(2).normal(size=(500, 3)) * 4])
    d, i = NearestTree(xyz).query(q, k=k, distance_upper_bound=bound)
    d_ref, i_ref = cKDTree(xyz).query(q, k=k, distance_upper_bound=bound)
    assert d.shape == d_ref.shape
    assert i.dtype == np.int64
    if k == 1:
        d, i, d_ref, i_ref = d[:, None], i[:, None], d_ref[:, None], i_ref[:, None]
    assert np.isfinite(d_ref).sum() > 0
    assert (~np.isfinite(d_ref)).sum() > 0 or bound == np.inf
    _same_neighbours(d, i, d_ref, i_ref, xyz, q)


def test_nearest_tree_pads_like_scipy_when_k_exceeds_the_points() -> None:
    from amrst.neighbours import NearestTree

    xyz = np.random.default_rng(0).normal(size=(4, 3))
    d, i = NearestTree(xyz).query(xyz, k=6)
    assert np.all(np.isinf(d[:, 4:]))
    assert np.all(i[:, 4:] == 4)
    d, i = NearestTree(np.zeros((0, 3))).query(xyz)
    assert np.all(np.isinf(d))
    assert np.all(i == 0)


@pytest.mark.parametrize("fill", [0.02, 0.05, 0.09])
def test_voxel_components_equal_the_kd_tree_pair_search(fill: float) -> None:
    """Same labels as connected_components at radius 1.75 (26-connectivity)."""
    from amrst.stages.features import connected_components, voxel_components

    rng = np.random.default_rng(int(fill * 100))
    grid = np.stack(np.meshgrid(*[np.arange(25)] * 3, indexing="ij"), -1).reshape(-1, 3)
    keys = grid[rng.random(len(grid)) < fill]
    keys = keys[rng.permutation(len(keys))]
    got = voxel_components(keys)
    want = connected_components(keys.astype(float), 1.75)
    np.testing.assert_array_equal(got, want)
    assert 1 < len(np.unique(got)) < len(keys)  # really several, really merged


def test_voxel_components_link_corners_only_and_handle_far_keys() -> None:
    from amrst.stages.features import voxel_components

    keys = np.array([[0, 0, 0], [1, 1, 1], [3, 1, 1], [5, 0, 0], [6, 0, 0]])
    np.testing.assert_array_equal(voxel_components(keys), [0, 0, 1, 2, 2])
    far = keys + np.array([0, 0, 1 << 20])  # beyond the packed codes: fallback
    np.testing.assert_array_equal(voxel_components(far), [0, 0, 1, 2, 2])
    assert len(voxel_components(np.zeros((0, 3), dtype=np.int64))) == 0


@pytest.mark.parametrize("offset", [0.0, 4.5e5, 6.4e6])
def test_gt_rmse_from_moments_equals_moving_the_points(offset: float) -> None:
    """truth_errors' gt_rmse against the direct formula, georeferenced points too."""
    from amrst.stages.metrics import truth_errors
    from amrst.types import apply_transform, make_transform

    rng = np.random.default_rng(int(offset) % 97)
    xyz = rng.normal(size=(20_000, 3)) * [3.0, 3.0, 8.0] + offset
    ax = rng.normal(size=3)
    ax /= np.linalg.norm(ax)
    for angle_deg, shift in ((0.01, 0.002), (0.5, 0.05), (30.0, 1.0)):
        a = np.radians(angle_deg)
        K = np.array([[0, -ax[2], ax[1]], [ax[2], 0, -ax[0]], [-ax[1], ax[0], 0]])
        R = np.eye(3) + np.sin(a) * K + (1 - np.cos(a)) * K @ K
        T_true = make_transform(np.eye(3), rng.normal(size=3))
        T_est = make_transform(R, T_true[:3, 3] + shift) @ np.eye(4)
        diff = apply_transform(T_est, xyz) - apply_transform(T_true, xyz)
        want = np.sqrt(np.mean(np.sum(diff**2, axis=1)))
        got = truth_errors(T_est, T_true, xyz).gt_rmse_m
        assert got == pytest.approx(want, rel=1e-6, abs=1e-9)
    assert truth_errors(np.eye(4), np.eye(4), xyz).gt_rmse_m == 0.0
    assert truth_errors(np.eye(4), np.eye(4), xyz[:0]).gt_rmse_m == 0.0
