"""Round-3 speed changes (issue 15) against a brute-force answer or the code they
replaced: the neighbour table's index-only read (rows with missing neighbours found
without a sort)."""

from __future__ import annotations

import numpy as np
import pytest

from amrst.neighbours import NeighbourTable


def _brute_knn(xyz: np.ndarray, k: int, rows: np.ndarray) -> np.ndarray:
    """Indices of the k nearest points of ``xyz[rows]`` by a full distance matrix."""
    d2 = ((xyz[rows][:, None, :] - xyz[None, :, :]) ** 2).sum(axis=2)
    return np.argsort(d2, axis=1, kind="stable")[:, :k]


def _cloud(seed: int, n: int) -> np.ndarray:
    """Random float points on a noisy cylinder: no two distances tie."""
    rng = np.random.default_rng(seed)
    a, z = rng.uniform(0, 2 * np.pi, n), rng.uniform(0, 2, n)
    xyz = np.column_stack([0.2 * np.cos(a), 0.2 * np.sin(a), z])
    return xyz + rng.normal(0, 0.01, xyz.shape)


@pytest.mark.parametrize("share", [0.97, 0.6, 0.15])
def test_view_reads_equal_brute_force(share: float) -> None:
    """Dense views (most rows read off the table), sparse ones (most rows asked
    afresh, some twice wider): ``knn`` and ``knn_idx`` give the brute-force
    neighbours, and the distances that go with them."""
    xyz = _cloud(int(share * 100), 2500)
    rng = np.random.default_rng(1)
    keep = np.flatnonzero(rng.random(len(xyz)) < share)
    view = NeighbourTable.build(xyz, 24).subset(keep)
    rows = np.sort(rng.choice(len(keep), len(keep) // 3, replace=False))
    sub = xyz[keep]
    for k in (1, 9, 17, 24):
        ref = _brute_knn(sub, k, rows)
        d, i = view.knn(k, rows)
        np.testing.assert_array_equal(i, ref)
        np.testing.assert_array_equal(view.knn_idx(k, rows), ref)
        np.testing.assert_allclose(
            d, np.linalg.norm(sub[rows][:, None] - sub[ref], axis=2), atol=1e-12
        )
    # Every row, and a k above the table's width (a fresh query on the view).
    np.testing.assert_array_equal(
        view.knn_idx(17), _brute_knn(sub, 17, np.arange(len(sub)))
    )
    np.testing.assert_array_equal(
        view.knn_idx(30, rows), _brute_knn(sub, 30, rows)
    )


def test_index_only_read_equals_the_full_read_on_the_whole_cloud() -> None:
    """On the whole cloud (no view) the index-only read is the table's own columns."""
    xyz = _cloud(7, 1500)
    table = NeighbourTable.build(xyz, 16)
    rows = np.arange(0, len(xyz), 5)
    np.testing.assert_array_equal(table.knn_idx(12, rows), table.knn(12, rows)[1])
    np.testing.assert_array_equal(table.knn_idx(16), table.knn(16)[1])
    np.testing.assert_array_equal(
        table.knn_idx(16), _brute_knn(xyz, 16, np.arange(len(xyz)))
    )

