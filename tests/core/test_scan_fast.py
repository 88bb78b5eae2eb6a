"""Per-scan kernels against reference implementations kept here: the neighbourhood
covariances and the neighbour table's subset reads."""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest

from amrst import neighbours
from amrst.neighbours import NeighbourTable, knn
from amrst.stages.features import _covariances, pairwise_rows


def _covariances_before(
    xyz: np.ndarray, idx: np.ndarray, ks: tuple[int, ...]
) -> list[tuple[np.ndarray, ...]]:
    """features._covariances as it was (fancy-index gather, per-row numpy sums)."""
    ks = tuple(min(k, idx.shape[1]) for k in ks)
    kmax = max(ks)
    g = xyz.T[:, idx[:, :kmax]]
    g = g - g[:, :, :1]
    x, y, z = g
    prods = (x, y, z, x * x, y * y, z * z, x * y, x * z, y * z)
    out = []
    sums: list[Any] = [0.0] * 9
    done = 0
    for k in sorted(set(ks)):
        sums = [s + p[:, done:k].sum(axis=1) for s, p in zip(sums, prods, strict=True)]
        done = k
        mx, my, mz = (v / k for v in sums[:3])
        a, b, c, d, e, f = (v / k for v in sums[3:])
        out.append(
            (
                a - mx * mx,
                b - my * my,
                c - mz * mz,
                d - mx * my,
                e - mx * mz,
                f - my * mz,
            )
        )
    by_k = dict(zip(sorted(set(ks)), out, strict=True))
    return [by_k[k] for k in ks]


@pytest.mark.parametrize(
    ("n", "m", "k", "ks"),
    [
        (5000, 3000, 30, (10, 30)),
        (3000, 2000, 100, (4, 37, 100)),
        (200, 150, 5, (10, 30)),  # tiny cloud: fewer neighbours than asked
        (4000, 500, 140, (7, 140)),  # runs over 128: numpy halves them first
    ],
)
def test_covariances_equal_the_per_row_sums(
    n: int, m: int, k: int, ks: tuple[int, ...]
) -> None:
    rng = np.random.default_rng(n)
    xyz = rng.normal(size=(n, 3)) * rng.exponential(size=(n, 1)) + [300.0, -20.0, 5.0]
    idx = rng.integers(0, n, (m, k))
    idx[:, 0] = rng.integers(0, n, m)
    got, ref = _covariances(xyz, idx, ks), _covariances_before(xyz, idx, ks)
    assert len(got) == len(ref) == len(ks)
    for g, r in zip(got, ref, strict=True):
        for a, b in zip(g, r, strict=True):
            # Same rounding as numpy's row sums (bit for bit on numpy 2.x).
            np.testing.assert_allclose(a, b, rtol=1e-12, atol=1e-15)
            if np.__version__.startswith("2."):
                np.testing.assert_array_equal(a, b)


@pytest.mark.parametrize("n", [1, 5, 8, 13, 16, 30, 129, 300])
def testpairwise_rows_is_a_sum(n: int) -> None:
    rng = np.random.default_rng(n)
    a = rng.normal(size=(2, n, 50)) * 10.0 ** rng.integers(-8, 8, (2, n, 50))
    np.testing.assert_allclose(
        pairwise_rows(a), a.sum(axis=1), rtol=1e-9, atol=1e-9 * np.abs(a).max()
    )
    np.testing.assert_array_equal(
        pairwise_rows(a), np.ascontiguousarray(a.transpose(0, 2, 1)).sum(axis=2)
    )


@pytest.mark.parametrize("keep_fraction", [0.99, 0.9, 0.5])
def test_table_subset_reads_every_path(keep_fraction: float) -> None:
    """Rows whose first k are all kept, rows that skip a few, rows left short: the
    same answer as a fresh query on the subset, on one thread or two."""
    rng = np.random.default_rng(7)
    xyz = np.round(rng.uniform(0, 3, (8000, 3)), 3)  # mm grid: some ties
    keep = np.flatnonzero(rng.random(len(xyz)) < keep_fraction)
    for threads in (1, 2):
        view = NeighbourTable.build(xyz, 24, threads=threads).subset(keep)
        rows = np.sort(rng.choice(len(keep), 3000, replace=False))
        for k in (1, 10, 22):
            d, i = view.knn(k, rows)
            d_ref, i_ref = knn(xyz[keep], k, xyz[keep][rows], threads=threads)
            np.testing.assert_array_equal(d, d_ref)
            # Equal distances may list their points in another order.
            same = i == i_ref
            assert same.mean() > 0.99
            np.testing.assert_allclose(
                np.linalg.norm(
                    xyz[keep][i[~same]] - xyz[keep][rows][np.nonzero(~same)[0]],
                    axis=1,
                ),
                d[~same],
            )


def test_small_batches_run_on_one_thread_with_the_same_answers() -> None:
    """Queries under SMALL_BATCH work run on one thread; big ones on ``threads``;
    the neighbours are the same either way."""
    assert neighbours._batch_threads(100, 1, 2) == 1
    assert neighbours._batch_threads(351, 64, 2) == 1
    assert neighbours._batch_threads(16_000, 32, 2) == 2
    assert neighbours._batch_threads(16_000, 32, 1) == 1
    assert neighbours._build_threads(16_000, 2) == 1
    assert neighbours._build_threads(200_000, 2) == 2
    rng = np.random.default_rng(11)
    pts = np.round(rng.uniform(0, 2, (30_000, 3)), 3)
    queries = rng.uniform(0, 2, (40_000, 3))  # 40,000 x (1 + 3): two threads
    tree = neighbours.NearestTree(pts, threads=2)
    big = tree.query(queries, k=1, distance_upper_bound=0.05)
    small = tree.query(queries[:500], k=1, distance_upper_bound=0.05)
    one = neighbours.NearestTree(pts, threads=1).query(
        queries, k=1, distance_upper_bound=0.05
    )
    for a, b in zip(big, one, strict=True):
        np.testing.assert_array_equal(a, b)
    for a, b in zip(small, one, strict=True):
        np.testing.assert_array_equal(a, b[:500])
