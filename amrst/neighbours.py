"""Nearest-neighbour queries on compiled KD-trees that import fast.

small_gicp's KD-tree (imports in about 0.2 s) measured faster than
``scipy.spatial.cKDTree`` on this project's clouds, one thread against scipy's
``workers=-1`` (ratios in one run, tree geometry from case 08, see
``docs/bench/scale/README.md``): 1.2-1.7x for :func:`knn` (build a tree, then the k
nearest of many points: the outlier filter, the wood features, the skeleton graph)
and 1.4-1.9x for :class:`NearestTree` queries (one tree, many queries: ICP
correspondences, cloud metrics). pykdtree was as fast with one OpenMP thread but
5-12x slower than scipy with two on this loaded 2-core machine (OpenMP threads
spin while they wait), so it is not used.

Both return what ``cKDTree.query`` returns: Euclidean distances sorted ascending and
int64 indices, ``inf`` and ``len(points)`` where no neighbour lies within the bound.
Neighbours at exactly equal distances may come in another order than scipy's.
"""

from __future__ import annotations

from typing import Any

import numpy as np


def _points(xyz: np.ndarray) -> np.ndarray:
    return np.ascontiguousarray(xyz, dtype=np.float64).reshape(-1, 3)


def knn(
    points: np.ndarray,
    k: int,
    queries: np.ndarray | None = None,
    threads: int = 1,
) -> tuple[np.ndarray, np.ndarray]:
    """Find the ``k`` nearest ``points`` of each query (of every point by default).

    Parameters
    ----------
    points : (N, 3) float64
    k : int
        1 <= k <= N.
    queries : (M, 3) float64 or None
        None queries every point (each point is then its own first neighbour).
    threads : int
        Threads for the build and the queries. The per-scan stages already run the two
        scans on one thread each, so 1 is right there.

    Returns
    -------
    dist : (M, k) float64, ascending
    idx : (M, k) int64
    """
    import small_gicp

    pts = _points(points)
    if not 1 <= k <= len(pts):
        raise ValueError(f"k must be within 1..{len(pts)}, not {k}")
    q = pts if queries is None else _points(queries)
    if len(q) == 0:
        return np.zeros((0, k)), np.zeros((0, k), dtype=np.int64)
    tree = small_gicp.KdTree(pts, num_threads=threads)
    idx, sq = tree.batch_knn_search(q, k, num_threads=threads)
    # Every index is valid (k <= N): the uint64 array reads as int64 without a copy.
    return np.sqrt(sq, out=sq), idx.view(np.int64)


class NearestTree:
    """One KD-tree on fixed points for repeated nearest-neighbour queries.

    Parameters
    ----------
    points : (N, 3) float64
        Copied when not C-contiguous float64.
    threads : int
        Threads for the build and each query.
    """

    def __init__(self, points: np.ndarray, threads: int = 1) -> None:
        import small_gicp

        self.points = _points(points)
        self.n = len(self.points)
        self.threads = threads
        self._tree: Any = (
            small_gicp.KdTree(self.points, num_threads=threads) if self.n else None
        )

    def query(
        self,
        queries: np.ndarray,
        k: int = 1,
        distance_upper_bound: float = np.inf,
    ) -> tuple[np.ndarray, np.ndarray]:
        """Return the ``k`` nearest points of each query closer than the bound.

        Parameters
        ----------
        queries : (M, 3) float64
        k : int
        distance_upper_bound : float
            Neighbours at this distance or farther are not returned (m), as in scipy.

        Returns
        -------
        dist : (M,) float64 when k == 1, else (M, k); ``inf`` where none was found
        idx : int64 of the same shape; ``len(points)`` where none was found
        """
        q = _points(queries)
        shape = (len(q),) if k == 1 else (len(q), k)
        if self.n == 0 or len(q) == 0:
            return np.full(shape, np.inf), np.full(shape, self.n, dtype=np.int64)
        idx, sq = self._tree.batch_knn_search(q, min(k, self.n), self.threads)
        dist = np.sqrt(sq)
        idx = idx.astype(np.int64)
        if k > self.n:  # pad like scipy
            pad = k - self.n
            dist = np.hstack([dist, np.full((len(q), pad), np.inf)])
            idx = np.hstack([idx, np.full((len(q), pad), self.n, dtype=np.int64)])
        far = ~(dist < distance_upper_bound)
        if far.any():
            dist[far], idx[far] = np.inf, self.n
        return dist.reshape(shape), idx.reshape(shape)
