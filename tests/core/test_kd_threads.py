"""KD-tree threads (amrst.neighbours): the same neighbours on one thread or two."""

from __future__ import annotations

import numpy as np

from amrst import neighbours


def test_one_or_two_threads_give_the_same_neighbours() -> None:
    rng = np.random.default_rng(3)
    pts = np.round(rng.uniform(0, 2, (20_000, 3)), 3)  # mm grid: ties occur
    queries = rng.uniform(0, 2, (5_000, 3))
    got = {}
    for n in (1, 2):
        tree = neighbours.NearestTree(pts, threads=n)
        assert tree.threads == n
        table = neighbours.NeighbourTable.build(pts, 16, threads=n)
        assert table.threads == n
        view = table.subset(np.arange(0, len(pts), 3))
        assert view.threads == n
        got[n] = (
            neighbours.knn(pts, 8, queries, threads=n),
            tree.query(queries, k=4, distance_upper_bound=0.05),
            table.knn(16),
            view.knn(12),
        )
    for a, b in zip(got[1], got[2], strict=True):
        np.testing.assert_array_equal(a[0], b[0])
        np.testing.assert_array_equal(a[1], b[1])
