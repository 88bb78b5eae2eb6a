"""Nearest-neighbour queries on small_gicp's compiled KD-trees.

small_gicp is used rather than ``scipy.spatial.cKDTree`` because it imports fast and
answers these clouds' queries faster. :func:`knn` builds a tree and finds the k
nearest of many points (the outlier filter, the wood features, the skeleton graph);
:class:`NearestTree` keeps one tree for repeated queries (ICP correspondences, cloud
metrics); :class:`NeighbourTable` shares one query between the per-scan stages.

Both return what ``cKDTree.query`` returns: Euclidean distances sorted ascending and
int64 indices, ``inf`` and ``len(points)`` where no neighbour lies within the bound.
Neighbours at exactly equal distances may come in another order than scipy's.
"""

from __future__ import annotations

import os
import threading
from typing import Any

import numpy as np

from amrst.guards import require_points

# The default threads of every KD-tree build and query: two where there are two
# cores, because small_gicp holds the GIL while it queries, so threads inside a query
# are what runs it in parallel. Callers that share the cores (a campaign worker, the app's engine) pass
# fewer; the answers never depend on the threads.
THREADS = min(2, os.cpu_count() or 1)


# A query of less work than this (queries x (neighbours + 3)) runs on one thread
# whatever ``threads`` says: waking a second OpenMP thread costs more than it saves on
# so little work. The answers do not depend on the threads.
SMALL_BATCH = 100_000

# Building a tree costs about as much per point as finding this many neighbours of a
# query (decides when a view gets its own tree, ``NeighbourTable``).
_BUILD_COST = 2


def _batch_threads(n_queries: int, k: int, threads: int) -> int:
    """Threads for ``n_queries`` queries of ``k`` neighbours (one for a small batch)."""
    return threads if n_queries * (k + 3) >= SMALL_BATCH else 1


def _build_threads(n_points: int, threads: int) -> int:
    """Threads for building a tree on ``n_points`` points.

    One below 100,000 points, where a second thread costs more than it saves.
    """
    return threads if n_points >= 100_000 else 1


def _points(xyz: np.ndarray) -> np.ndarray:
    return np.ascontiguousarray(xyz, dtype=np.float64).reshape(-1, 3)


def _kdtree(points: np.ndarray, threads: int) -> Any:
    """Build small_gicp's KD-tree on ``points`` (C-contiguous (N, 3) float64).

    A query of a tree on no points ends the process, and a NaN or infinite point
    makes its answers wrong without an error: both are refused first.

    Raises
    ------
    InvalidInput
        No points, or a NaN/inf coordinate.
    """
    import small_gicp

    require_points(points, "the cloud searched for neighbours")
    return small_gicp.KdTree(points, num_threads=_build_threads(len(points), threads))


def knn(
    points: np.ndarray,
    k: int,
    queries: np.ndarray | None = None,
    threads: int = THREADS,
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
        Threads for the build and the queries (a small batch uses one).

    Returns
    -------
    dist : (M, k) float64, ascending
    idx : (M, k) int64
    """
    pts = _points(points)
    if not 1 <= k <= len(pts):
        raise ValueError(f"k must be within 1..{len(pts)}, not {k}")
    q = pts if queries is None else _points(queries)
    if len(q) == 0:
        return np.zeros((0, k)), np.zeros((0, k), dtype=np.int64)
    tree = _kdtree(pts, threads)
    idx, sq = tree.batch_knn_search(
        q, k, num_threads=_batch_threads(len(q), k, threads)
    )
    # Every index is valid (k <= N): the uint64 array reads as int64 without a copy.
    return np.sqrt(sq, out=sq), idx.view(np.int64)


class _Tree:
    """A small_gicp KdTree on fixed points, built on first use after unpickling.

    small_gicp's trees cannot be pickled, and the app sends the analyses that hold
    them to its engine process and back. A tree pickles as nothing and
    is built again, from the same points with the same code (so every answer is
    the same), only where it is queried.
    """

    def __init__(self, points: np.ndarray, threads: int, tree: Any = None) -> None:
        self._points, self._threads, self._tree = points, threads, tree
        self._lock = threading.Lock()

    def get(self) -> Any:
        """Return the tree, built now if it was not yet."""
        with self._lock:
            if self._tree is None:
                self._tree = _kdtree(self._points, self._threads)
            return self._tree

    def __getstate__(self) -> dict[str, Any]:
        return {"points": self._points, "threads": self._threads}

    def __setstate__(self, state: dict[str, Any]) -> None:
        self.__init__(state["points"], state["threads"])  # type: ignore[misc]


class NearestTree:
    """One KD-tree on fixed points for repeated nearest-neighbour queries.

    Parameters
    ----------
    points : (N, 3) float64
        Copied when not C-contiguous float64.
    threads : int
        Threads for the build and each query (a small one uses one).
    """

    def __init__(self, points: np.ndarray, threads: int = THREADS) -> None:
        self.points = _points(points)
        self.n = len(self.points)
        self.threads = threads
        self._tree: _Tree | None = (
            _Tree(self.points, self.threads, _kdtree(self.points, self.threads))
            if self.n
            else None
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
        kk = min(k, self.n)
        assert self._tree is not None  # n > 0
        idx, sq = self._tree.get().batch_knn_search(
            q, kk, _batch_threads(len(q), kk, self.threads)
        )
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


class NeighbourTable:
    """The ``K`` nearest neighbours of every point of a cloud, from one query.

    The per-scan stages each needed a k-nearest query on a subset of the same
    preprocessed points (the outlier filter on all of them, the wood features on the
    points left after the outlier filter and the scene cut, the skeleton graph on a
    voxel sample of those). The k nearest points of a subset are the first k of the
    cloud's neighbours that belong to the subset, whenever the K listed hold k of
    them: :meth:`knn` reads them off the table, asks the cloud's tree for 2K (then
    8K, 32K, ...) neighbours of the rows where too few remain, and queries the subset
    afresh only when that would cost more than a tree on the subset. The answer
    equals :func:`knn` on the subset, but for the order of neighbours at exactly
    equal distances. Per-scan stages: one KD-tree build and one query per scan
    instead of three of each.

    Parameters
    ----------
    points : (M, 3) float64
        The whole cloud.
    dist, idx : (M, K) float64 and int64
        :func:`knn` of every point of ``points`` (each point its own first neighbour).
    pos : (N,) int64 or None
        Sorted positions in ``points`` of the points this view stands for; None: all.
    tree : small_gicp.KdTree or None
        The tree on ``points`` (None: rows left short are queried afresh).
    threads : int
        Threads for the queries this view makes (a small one uses one).
    """

    def __init__(
        self,
        points: np.ndarray,
        dist: np.ndarray,
        idx: np.ndarray,
        pos: np.ndarray | None = None,
        tree: Any = None,
        threads: int = THREADS,
    ) -> None:
        self._points, self._dist, self._idx, self._pos = points, dist, idx, pos
        self.threads = threads
        # small_gicp.KdTree on points, for the rows left short
        self._tree = (
            tree
            if tree is None or isinstance(tree, _Tree)
            else _Tree(points, threads, tree)
        )

    @classmethod
    def build(
        cls, points: np.ndarray, k: int, threads: int = THREADS
    ) -> NeighbourTable:
        """Query the ``k`` nearest neighbours of every point (k capped at the points).

        ``threads``: for this query and the ones the table makes later.
        """
        pts = _points(points)
        k = min(k, len(pts))
        if k < 1:
            raise ValueError("a neighbour table needs at least one point")
        tree = _kdtree(pts, threads)
        idx, sq = tree.batch_knn_search(
            pts, k, num_threads=_batch_threads(len(pts), k, threads)
        )
        return cls(pts, np.sqrt(sq, out=sq), idx.view(np.int64), None, tree, threads)

    @property
    def k(self) -> int:
        """Neighbours listed per point (K)."""
        return int(self._idx.shape[1])

    @property
    def xyz(self) -> np.ndarray:
        """(N, 3) the points of this view."""
        return self._points if self._pos is None else self._points[self._pos]

    def __len__(self) -> int:
        return len(self._points) if self._pos is None else len(self._pos)

    def subset(self, pos: np.ndarray) -> NeighbourTable:
        """Return the view of the points at ``pos`` (sorted positions in this view)."""
        pos = np.asarray(pos, dtype=np.int64)
        if self._pos is not None:
            pos = self._pos[pos]
        return NeighbourTable(
            self._points, self._dist, self._idx, pos, self._tree, self.threads
        )

    def knn(
        self, k: int, rows: np.ndarray | None = None
    ) -> tuple[np.ndarray, np.ndarray]:
        """Return ``knn(self.xyz, k, self.xyz[rows])`` (every point when rows is None)."""
        dist, idx = self._knn(k, rows, True)
        assert dist is not None
        return dist, idx

    def knn_idx(self, k: int, rows: np.ndarray | None = None) -> np.ndarray:
        """Return the indices of :meth:`knn` alone (no distances gathered)."""
        return self._knn(k, rows, False)[1]

    def _knn(
        self, k: int, rows: np.ndarray | None, with_dist: bool
    ) -> tuple[np.ndarray | None, np.ndarray]:
        n = len(self)
        if not 1 <= k <= n:
            raise ValueError(f"k must be within 1..{n}, not {k}")
        if rows is None and self._pos is None and k <= self.k:
            return self._dist[:, :k], self._idx[:, :k]
        rows = np.arange(n) if rows is None else np.asarray(rows, dtype=np.int64)
        root = rows if self._pos is None else self._pos[rows]
        if self._pos is None and k <= self.k:
            return (
                np.take(self._dist[:, :k], root, axis=0) if with_dist else None,
                np.take(self._idx[:, :k], root, axis=0),
            )
        if self._pos is None or k > self.k:
            return knn(self.xyz, k, self.xyz[rows], self.threads)
        inv = np.full(len(self._points), -1, dtype=np.int64)
        inv[self._pos] = np.arange(n)
        # np.take rather than fancy indexing: faster on these shapes.
        idx = np.take(inv, np.take(self._idx[:, :k], root, axis=0))
        dist = np.take(self._dist[:, :k], root, axis=0) if with_dist else None
        # Most rows have their first k listed
        # neighbours in the view: those are the answer as they stand. The others
        # take the first k of their listed neighbours that are in the view (only
        # their rows of all K are gathered). Rows with any missing: the flat
        # positions come sorted, so their rows come in runs (no np.unique sort).
        part = np.flatnonzero(idx.ravel() < 0) // k
        part = part[np.r_[True, part[1:] != part[:-1]]] if len(part) else part
        jp = np.take(inv, np.take(self._idx, root[part], axis=0))
        at = np.flatnonzero(jp.ravel() >= 0)
        count = np.bincount(at // jp.shape[1], minlength=len(part))
        ok = count >= k
        start = np.cumsum(count) - count
        take = at[(start[ok][:, None] + np.arange(k)).ravel()]
        if dist is not None:
            dist[part[ok]] = (
                np.take(self._dist, root[part], axis=0).ravel()[take].reshape(-1, k)
            )
        idx[part[ok]] = jp.ravel()[take].reshape(-1, k)
        short = part[~ok]
        # More of the cloud's neighbours for the rows left short: 2K, then
        # four times more while that costs less than a tree on the view would. A
        # sparse view (the skeleton's voxel sample, with many rows short) gets
        # that tree straight away: building it costs about two neighbours' search per
        # point, and each short row then asks k neighbours instead of 2K.
        wide, n_all = min(2 * self.k, len(self._points)), len(self._points)
        if len(short) * (wide - k) > _BUILD_COST * n:
            wide = 0  # skip the wider reads
        while wide and len(short) and self._tree is not None:
            w_idx, w_sq = self._tree.get().batch_knn_search(
                self._points[root[short]],
                wide,
                num_threads=_batch_threads(len(short), wide, self.threads),
            )
            jw = inv[w_idx.view(np.int64)]
            at = np.flatnonzero(jw.ravel() >= 0)
            count = np.bincount(at // wide, minlength=len(short))
            got = count >= k
            start = np.cumsum(count) - count
            take = at[(start[got][:, None] + np.arange(k)).ravel()]
            if dist is not None:
                dist[short[got]] = np.sqrt(w_sq.ravel()[take]).reshape(-1, k)
            idx[short[got]] = jw.ravel()[take].reshape(-1, k)
            short = short[~got]
            wide_next = min(4 * wide, n_all)
            if wide == n_all or len(short) * wide_next > 4 * n_all:
                break
            wide = wide_next
        if len(short):
            xyz = self.xyz
            d_short, idx[short] = knn(xyz, k, xyz[rows[short]], self.threads)
            if dist is not None:
                dist[short] = d_short
        return dist, idx
