"""Nearest-neighbour correspondences kept across ICP iterations, re-queried only when needed.

Both ICPs of the pipeline (the batched polish of the coarse stage and the trunk
search, and the fine stage's LM-ICP) ask, every iteration, for the nearest target
point within ``max_dist`` of every moved source point. Their steps shrink fast, so
most points keep the partner they had: :class:`NearestCache` remembers it and asks
the KD-tree again only for points that may have changed (bit for bit the same
partners as a fresh query, see the class).
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Protocol

import numpy as np

if TYPE_CHECKING:
    from collections.abc import Callable


class NearestQuery(Protocol):
    """A KD-tree on the target points.

    ``scipy.spatial.cKDTree`` or :class:`amrst.neighbours.NearestTree`.
    """

    def query(
        self, x: np.ndarray, k: int = ..., *, distance_upper_bound: float = ...
    ) -> tuple[np.ndarray, np.ndarray]:
        """Distances and indices of the ``k`` nearest points within the bound."""


class NearestCache:
    """The nearest target point within ``max_dist`` of each moved source point.

    Exactly as a KD-tree query would return it, re-queried only for points that may
    have changed.

    A query keeps the two nearest distances d1 <= d2 (within 1.5 max_dist). While a
    point has moved less than (d2 - d1) / 2 since, no other target point can have come
    closer than the old one (triangle inequality); while it has moved less than
    d1 - max_dist, none can have come within max_dist (it stays without a match); a
    point with nothing within 1.5 max_dist stays without a match while it has moved
    less than max_dist / 2.
    ICP steps shrink fast, so most point queries are skipped, and the transforms are
    the same bit for bit.

    Parameters
    ----------
    tree : NearestQuery
        A KD-tree on ``tgt``.
    tgt : (N, 3) float64
    n : int
        Number of source points (rows) tracked.
    max_dist : float
        The first (largest) correspondence distance; later ones may only be smaller
        (set ``max_dist`` between calls).
    near : callable or None
        ``near(points) -> (M,) bool``, False only for points with no target point
        within ``reach`` (1.5 max_dist): those are not asked (a KD-tree without a
        distance bound, small_gicp's, searches far points as long as near ones).
    """

    def __init__(
        self,
        tree: NearestQuery,
        tgt: np.ndarray,
        n: int,
        max_dist: float,
        near: Callable[[np.ndarray], np.ndarray] | None = None,
    ) -> None:
        self.tree, self.tgt, self.max_dist, self.near = tree, tgt, max_dist, near
        # Kept across scales of decreasing max_dist: the slacks stay valid (a point
        # with nothing within reach has even more room for a smaller max_dist).
        self.reach = 1.5 * max_dist
        self.ref = np.zeros((n, 3))  # where each point was at its last query
        self.q = np.full(
            (n, 3), np.inf
        )  # its nearest target point (inf: none in reach)
        self.slack2 = np.full(n, -1.0)  # squared movement allowed before a new query

    def match(
        self, p: np.ndarray, rows: np.ndarray | None = None
    ) -> tuple[np.ndarray, np.ndarray]:
        """Return the points with a match within max_dist and their matches.

        Parameters
        ----------
        p : (M, 3) float64
            Where the tracked points are now: all n of them, or the ``rows`` given.
        rows : (M,) int64 or None
            Which tracked points ``p`` holds (None: all, in order).

        Returns
        -------
        inside : (K,) int64
            Positions in ``p`` of the points with a match.
        q : (K, 3) float64
            Their nearest target points.
        """
        q = self.nearest(p, rows)
        off = p - q
        inside = np.flatnonzero(np.einsum("ij,ij->i", off, off) < self.max_dist**2)
        return inside, q[inside]

    def nearest(self, p: np.ndarray, rows: np.ndarray | None = None) -> np.ndarray:
        """Return each point's partner: its nearest target point when within max_dist.

        (M, 3) float64; ``p`` and ``rows`` as in :meth:`match`. A point with no target
        point within max_dist gets some target point at least max_dist away, or
        ``inf``.
        """
        if rows is None:
            ref, slack2 = self.ref, self.slack2
        else:
            ref, slack2 = self.ref[rows], self.slack2[rows]
        step = p - ref
        stale = np.flatnonzero(np.einsum("ij,ij->i", step, step) >= slack2)
        at = stale if rows is None else rows[stale]
        if len(stale):
            moved = p[stale]
            if self.near is None:  # every stale point is asked
                d, jj = self.tree.query(moved, k=2, distance_upper_bound=self.reach)
            else:
                d = np.full((len(stale), 2), np.inf)
                jj = np.full((len(stale), 2), len(self.tgt), dtype=np.int64)
                ask = self.near(moved)
                d[ask], jj[ask] = self.tree.query(
                    moved[ask], k=2, distance_upper_bound=self.reach
                )
            self.ref[at] = moved
            found = jj[:, 0] < len(self.tgt)
            self.q[at[found]] = self.tgt[jj[found, 0]]
            self.q[at[~found]] = np.inf
            d1, d2 = d[:, 0], np.minimum(d[:, 1], self.reach)
            # A point farther than max_dist from every target point needs no new
            # query while it stays farther: d1 - max_dist (max_dist only shrinks).
            free = np.where(
                found,
                np.maximum((d2 - d1) / 2, d1 - self.max_dist),
                self.reach - self.max_dist,
            )
            free -= 1e-9  # margin for rounding
            self.slack2[at] = np.where(free > 0, free * free, -1.0)
        return self.q if rows is None else self.q[rows]
