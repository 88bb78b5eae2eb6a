"""Per-scan row reductions against reference implementations kept here:
the outlier filter's mean neighbour distance, the wood vote's neighbourhood mean,
the finite-point mask and the neighbour table's subset reads."""

from __future__ import annotations

import numpy as np
import pytest

from amrst.neighbours import NeighbourTable, knn
from amrst.stages.features import pairwise_rows
from amrst.stages.preprocess import PreprocessParams, preprocess_points


def _trunk(rng: np.random.Generator, n: int) -> np.ndarray:
    """A noisy 30 cm trunk with a few far outliers."""
    a, z = rng.uniform(0, 2 * np.pi, n), rng.uniform(0, 3, n)
    xyz = np.column_stack([0.15 * np.cos(a), 0.15 * np.sin(a), z])
    xyz += rng.normal(0, 0.003, xyz.shape)
    xyz[rng.choice(n, 20, replace=False)] += rng.uniform(-1, 1, (20, 3))
    return xyz


@pytest.mark.parametrize("k", [1, 3, 7, 8, 12, 13, 30, 64])
def test_column_sums_are_numpys_row_means(k: int) -> None:
    """Summing whole rows in numpy's pairwise order gives ``mean(axis=1)`` bit for
    bit, on a strided view (the outlier filter) and on a gather (the wood vote)."""
    rng = np.random.default_rng(k)
    dist = np.sort(rng.random((3000, 70)) * rng.random((3000, 1)), axis=1)
    view = dist[:, : k + 1][:, 1:]
    np.testing.assert_array_equal(pairwise_rows(view.T[None])[0] / k, view.mean(axis=1))
    vote = rng.random(5000)
    nbr = rng.integers(0, len(vote), (2000, 70))
    np.testing.assert_array_equal(
        pairwise_rows(np.take(vote, nbr[:, :k].T)[None])[0] / k,
        vote[nbr[:, :k]].mean(axis=1),
    )


def test_outlier_filter_keeps_what_the_row_mean_kept() -> None:
    """The statistical filter keeps exactly the points the per-row mean kept."""
    rng = np.random.default_rng(3)
    xyz = _trunk(rng, 6000)
    params = PreprocessParams(voxel_size_m=0.0, outlier_neighbours=12)
    got = preprocess_points(xyz, params)
    d = knn(xyz, 13)[0][:, 1:].mean(axis=1)  # the rule as it was written
    kept = np.flatnonzero(d <= d.mean() + 3.0 * d.std())
    np.testing.assert_array_equal(got.index, kept)
    assert got.n_outliers == len(xyz) - len(kept) > 0


def test_non_finite_rows_are_dropped_column_by_column() -> None:
    """A NaN or inf in any one coordinate drops that point and only that one."""
    rng = np.random.default_rng(4)
    xyz = _trunk(rng, 3000)
    bad = np.array([5, 17, 2999])
    xyz[5, 0], xyz[17, 1], xyz[2999, 2] = np.nan, np.inf, -np.inf
    got = preprocess_points(
        xyz, PreprocessParams(voxel_size_m=0.0, outlier_neighbours=0)
    )
    assert got.n_invalid == 3
    np.testing.assert_array_equal(got.index, np.setdiff1d(np.arange(len(xyz)), bad))


def test_table_view_full_rows_match_a_fresh_query() -> None:
    """A view read of every row (the skeleton's call) equals a fresh query on the view."""
    rng = np.random.default_rng(5)
    xyz = _trunk(rng, 8000)
    keep = np.flatnonzero(rng.random(len(xyz)) < 0.6)
    d, i = NeighbourTable.build(xyz, 32).subset(keep).knn(17)
    d_ref, i_ref = knn(xyz[keep], 17)
    np.testing.assert_array_equal(d, d_ref)
    np.testing.assert_array_equal(i, i_ref)
