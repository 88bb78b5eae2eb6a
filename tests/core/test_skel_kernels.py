"""Scene and skeleton kernels against reference implementations kept here or a
brute-force answer: every one must give the same bits."""

from __future__ import annotations

import contextlib

import numpy as np
import pytest


@pytest.mark.parametrize("n_cells", [3, 6, 40])
def test_draw_solves_equal_numpys_solve_one_by_one(n_cells: int) -> None:
    """One kernel call gives np.linalg.solve's answer for every draw, NaN where that
    refuses the system: cells drawn twice (some singular, some not after LAPACK's
    reciprocal pivot) and three cells on one line."""
    from amrst.stages.ground import _halve_draws, _solve_draws

    rng = np.random.default_rng(n_cells)
    xy = rng.uniform(-5, 5, (n_cells, 2))
    xy[2] = xy[0] + 0.5 * (xy[1] - xy[0])  # on the line through cells 0 and 1
    A = np.column_stack([xy, np.ones(n_cells)])
    z = rng.normal(0, 1, n_cells)
    draws = rng.integers(0, n_cells, size=(500, 3))
    draws[:3] = [[0, 1, 2], [1, 1, 0], [2, 0, 0]]
    got = _solve_draws(A[draws], z[draws])
    want = np.full((len(draws), 3), np.nan)
    for i, d in enumerate(draws):
        with contextlib.suppress(np.linalg.LinAlgError):
            want[i] = np.linalg.solve(A[d], z[d])
    assert np.isnan(want).any(axis=1).sum() > 0  # the case is exercised
    np.testing.assert_array_equal(got, want)
    np.testing.assert_array_equal(_halve_draws(A[draws], z[draws]), want)


@pytest.mark.parametrize("dtype", [np.float64, np.float32, np.int64])
def test_column_min_equals_numpys_min_over_rows(dtype: type) -> None:
    from amrst.stages.voxels import column_min

    rng = np.random.default_rng(4)
    for cols in (2, 3):
        a = (rng.normal(0, 100, (1001, cols))).astype(dtype)
        got = column_min(a)
        assert got.dtype == a.min(axis=0).dtype
        np.testing.assert_array_equal(got, a.min(axis=0))


def test_finite_rows_equals_numpys_all_over_rows() -> None:
    from amrst.stages.voxels import finite_rows

    rng = np.random.default_rng(5)
    for cols in (1, 2, 3):
        a = rng.normal(0, 1, (500, cols))
        a[rng.choice(500, 40, replace=False), rng.integers(0, cols, 40)] = np.nan
        a[rng.choice(500, 10, replace=False), rng.integers(0, cols, 10)] = np.inf
        a[7, cols - 1] = -np.inf
        np.testing.assert_array_equal(finite_rows(a), np.isfinite(a).all(axis=1))


@pytest.mark.parametrize("seed", [0, 1])
def test_pairs_within_equal_the_default_tree_and_brute_force(seed: int) -> None:
    """The faster-built tree finds the same pairs as scipy's default tree and as
    every distance computed, on a cloud with points on a mm grid (equal distances)."""
    from scipy.spatial import cKDTree

    from amrst.stages.stems import _pairs_within

    rng = np.random.default_rng(seed)
    pts = np.round(rng.uniform(0, 1.5, (3000, 3)) * [1, 1, 0.3], 3)
    got = _pairs_within(pts, 0.06)
    assert np.all(got[:, 0] < got[:, 1])

    def as_set(p: np.ndarray) -> set[tuple[int, int]]:
        return set(map(tuple, p.tolist()))

    old = cKDTree(pts).query_pairs(0.06, output_type="ndarray")
    assert as_set(got) == as_set(old)
    assert len(got) == len(old)
    d = np.linalg.norm(pts[:, None] - pts[None], axis=2)
    i, j = np.nonzero(np.triu(d <= 0.06, 1))
    assert as_set(got) == as_set(np.column_stack([i, j]))


@pytest.mark.parametrize("voxel", [0.01, 0.05, 0.3])
def test_voxel_sample_without_owners_names_the_same_points(voxel: float) -> None:
    from amrst.stages.voxels import voxel_representatives, voxel_sample

    rng = np.random.default_rng(6)
    xyz = np.round(rng.normal(0, 1, (20_000, 3)), 2)  # duplicates: ties
    reps, owner = voxel_representatives(xyz, voxel)
    np.testing.assert_array_equal(voxel_sample(xyz, voxel), reps)
    assert len(owner) == len(xyz)
