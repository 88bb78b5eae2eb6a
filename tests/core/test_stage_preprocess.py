"""Preprocess: invalid rows, statistical outliers, voxel thinning, too few points."""

from __future__ import annotations

import logging

import numpy as np
import pytest

from amrst.errors import InvalidInput
from amrst.stages.preprocess import PreprocessParams, preprocess_points
from amrst.stages.voxels import voxel_representatives

NO_FILTERS = PreprocessParams(outlier_neighbours=0, voxel_size_m=0.0, min_points=10)


def _blob(n: int = 2000, seed: int = 0) -> np.ndarray:
    """A dense uniform blob: 1 m cube, about 8 cm spacing."""
    return np.random.default_rng(seed).uniform(0.0, 1.0, (n, 3))


def _readonly(a: np.ndarray) -> np.ndarray:
    a = np.array(a, dtype=np.float64)
    a.setflags(write=False)
    return a


def test_invalid_rows_are_dropped_and_counted() -> None:
    xyz = _blob(500)
    bad_rows = [3, 10, 11, 200, 499]
    xyz[3, 0] = np.nan
    xyz[10, 2] = np.inf
    xyz[11] = np.nan
    xyz[200, 1] = -np.inf
    xyz[499, 2] = np.nan
    res = preprocess_points(_readonly(xyz), NO_FILTERS)
    assert res.n_input == 500
    assert res.n_invalid == len(bad_rows)
    assert res.n_outliers == 0
    assert res.n_thinned == 0
    expected = np.setdiff1d(np.arange(500), bad_rows)
    np.testing.assert_array_equal(res.index, expected)
    np.testing.assert_array_equal(res.xyz, xyz[expected])
    assert np.isfinite(res.xyz).all()


def test_statistical_outliers_are_removed_and_counted() -> None:
    blob = _blob(2000)
    far = np.array(
        [[10.0, 0, 0], [0, -12.0, 0], [0, 0, 15.0], [-9.0, 9.0, 0], [8.0, 8.0, -8.0]]
    )
    xyz = np.vstack([blob[:1000], far, blob[1000:]])
    far_idx = np.arange(1000, 1005)
    params = PreprocessParams(voxel_size_m=0.0, min_points=10)
    res = preprocess_points(_readonly(xyz), params)
    assert res.n_outliers == 5
    assert res.n_invalid == 0
    assert not np.isin(far_idx, res.index).any(), "a far point survived"
    assert len(res.index) == 2000
    np.testing.assert_array_equal(res.xyz, xyz[res.index])
    # Without the filter they all stay: the count really comes from the filter.
    res_off = preprocess_points(_readonly(xyz), NO_FILTERS)
    assert res_off.n_outliers == 0
    assert np.isin(far_idx, res_off.index).all()


def _occupied_voxels(xyz: np.ndarray, voxel: float) -> dict[tuple, list[int]]:
    """Brute force: voxel key (grid anchored at the minimum corner) -> point indices."""
    lo = xyz.min(axis=0)
    out: dict[tuple, list[int]] = {}
    for i, p in enumerate(xyz):
        key = tuple(int(k) for k in np.floor((p - lo) / voxel))
        out.setdefault(key, []).append(i)
    return out


def test_voxel_thinning_keeps_one_real_point_per_occupied_voxel() -> None:
    rng = np.random.default_rng(5)
    xyz = rng.uniform(0.0, 1.0, (3000, 3)) * [2.0, 1.0, 0.5]
    voxel = 0.1
    params = PreprocessParams(outlier_neighbours=0, voxel_size_m=voxel, min_points=10)
    res = preprocess_points(_readonly(xyz), params)
    voxels = _occupied_voxels(xyz, voxel)
    assert len(res.index) == len(voxels)
    assert res.n_thinned == len(xyz) - len(voxels)
    # Real points (not centroids), valid and unique indices, one per voxel.
    assert res.index.min() >= 0
    assert res.index.max() < len(xyz)
    assert len(np.unique(res.index)) == len(res.index)
    np.testing.assert_array_equal(res.xyz, xyz[res.index])
    voxel_of = {i: key for key, members in voxels.items() for i in members}
    assert {voxel_of[int(i)] for i in res.index} == set(voxels)
    # Each kept point is the member nearest its voxel's centroid.
    for i in res.index[:200]:
        members = voxels[voxel_of[int(i)]]
        centroid = xyz[members].mean(axis=0)
        d = np.linalg.norm(xyz[members] - centroid, axis=1)
        assert members[int(np.argmin(d))] == i


def test_voxel_representatives_name_each_points_owner() -> None:
    """Brute force: the owner of every point is its own voxel's representative, ties
    in distance to the centroid go to the lowest index."""
    rng = np.random.default_rng(6)
    xyz = rng.uniform(0.0, 1.0, (2000, 3))
    xyz = np.vstack([xyz, xyz[:50]])  # exact duplicates: ties
    voxel = 0.2
    reps, owner = voxel_representatives(xyz, voxel)
    assert np.all(np.diff(reps) > 0)
    voxels = _occupied_voxels(xyz, voxel)
    assert len(reps) == len(voxels)
    for members in voxels.values():
        centroid = xyz[members].mean(axis=0)
        d = np.sum((xyz[members] - centroid) ** 2, axis=1)
        rep = members[int(np.argmin(d))]  # first (lowest index) of the nearest
        assert rep in reps
        np.testing.assert_array_equal(reps[owner[members]], rep)


def test_voxel_thinning_of_clusters_gives_one_point_per_cluster() -> None:
    """Clusters 2 voxels apart, each within the middle 40 % of one voxel of a grid
    anchored at a corner point: exactly one point per cluster."""
    rng = np.random.default_rng(9)
    voxel = 0.05
    centres = (
        np.stack(
            np.meshgrid(np.arange(6), np.arange(5), np.arange(4), indexing="ij"), -1
        ).reshape(-1, 3)
        * (2 * voxel)
        + 0.5 * voxel
    )
    xyz = np.repeat(centres, 7, axis=0) + rng.uniform(
        -0.2 * voxel, 0.2 * voxel, (len(centres) * 7, 3)
    )
    xyz = np.vstack([xyz, [[0.0, 0.0, 0.0]]])  # the grid's corner, in cluster 0's voxel
    params = PreprocessParams(outlier_neighbours=0, voxel_size_m=voxel, min_points=10)
    res = preprocess_points(_readonly(xyz), params)
    assert len(res.index) == len(centres) == 120
    cluster = np.where(res.index < 840, res.index // 7, 0)
    np.testing.assert_array_equal(np.sort(cluster), np.arange(120))


def test_too_few_points_raise_invalid_input() -> None:
    xyz = _blob(150)
    with pytest.raises(InvalidInput, match=r"Only 150 usable point\(s\).*at least 200"):
        preprocess_points(xyz, PreprocessParams(outlier_neighbours=0, min_points=200))
    all_nan = np.full((300, 3), np.nan)
    with pytest.raises(InvalidInput, match="300 read, 300 invalid"):
        preprocess_points(all_nan, PreprocessParams(min_points=10))
    # A sparse scan a few points short: no question of its units.
    few = _blob(190)
    with pytest.raises(InvalidInput, match=r"20 merged.*does the file hold a whole"):
        preprocess_points(
            np.vstack([few, few[:20]]),
            PreprocessParams(outlier_neighbours=0, min_points=200),
        )


def test_inputs_are_not_modified() -> None:
    xyz = _blob(1500)
    xyz[7] = np.nan
    xyz = np.vstack([xyz, [[20.0, 20.0, 20.0]]])
    before = xyz.copy()
    frozen = _readonly(xyz)  # writing into it would raise ValueError
    res = preprocess_points(frozen, PreprocessParams(voxel_size_m=0.05, min_points=10))
    np.testing.assert_array_equal(frozen, before)
    assert not np.shares_memory(res.xyz, frozen)
    assert res.n_invalid == 1
    assert res.n_outliers >= 1


@pytest.mark.parametrize(
    "bad",
    [
        {"outlier_neighbours": -1},
        {"outlier_std_ratio": 0.0},
        {"voxel_size_m": -0.01},
    ],
)
def test_params_refuse_negative_values(bad) -> None:
    with pytest.raises(ValueError, match="non-negative"):
        PreprocessParams(**bad)


def test_huge_scans_are_thinned_to_max_points(caplog) -> None:
    from amrst.stages.preprocess import PreprocessParams, preprocess_points

    rng = np.random.default_rng(3)
    xyz = rng.uniform(0, 10, size=(60_000, 3))
    params = PreprocessParams(voxel_size_m=0.01, max_points=5_000, outlier_neighbours=0)
    with caplog.at_level(logging.INFO, logger="amrst"):
        res = preprocess_points(xyz, params)
    assert len(res.xyz) <= 5_000
    assert len(res.xyz) > 1_000  # thinned, not emptied
    assert np.array_equal(xyz[res.index], res.xyz)  # still real points, valid indices
    assert "Large scan" in caplog.text
