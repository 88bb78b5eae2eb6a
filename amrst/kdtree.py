"""Compiled KD-trees behind one interface, and the threads they may use.

Two libraries, each where it measured best (``docs/bench/kdtree/README.md``):

- **pykdtree** for trees under :data:`PYKDTREE_MAX_POINTS` points: every tree of
  the shared cases (5-60 thousand points). It releases the GIL while it builds and
  queries, so the two scans of a pair, analysed in two threads
  (:func:`amrst.pipeline.analysis.both_scans`), really run at once; small_gicp holds
  the GIL while it queries, and the two scans' threads took turns. Its builds are
  several times faster than small_gicp's at these sizes, its queries 0.9-1.1x as
  fast.
- **small_gicp** for larger trees (the dense scans of issue 15): its parallel build
  and queries were 1.1-1.4x faster than pykdtree's at 2,000,000 points.

Both answer as ``cKDTree.query`` does: neighbours sorted by distance (squared
distances here), int64 indices. Neighbours at exactly equal distances may come in
another order in the two libraries, and a squared distance may differ in its last
bit (the sum is taken in another order).
"""

from __future__ import annotations

import ctypes
import functools
import os
import threading
from contextlib import contextmanager
from typing import TYPE_CHECKING, Any, Protocol

import numpy as np

if TYPE_CHECKING:
    from collections.abc import Callable, Iterator

# Trees on fewer points than this are pykdtree's (when it imports), larger ones
# small_gicp's.
PYKDTREE_MAX_POINTS = 100_000

# Threads for each KD-tree build and query (AMRST_KD_THREADS, default: 2 on a machine
# with 2 cores or more). A batch worker with one core sets 1 (amrst.campaign.run).
_threads = int(os.environ.get("AMRST_KD_THREADS", "0") or 0) or min(
    2, os.cpu_count() or 1
)
_local = threading.local()


def set_threads(n: int) -> None:
    """Set the threads every KD-tree build and query uses from now on (>= 1)."""
    global _threads
    _threads = max(1, int(n))


def threads() -> int:
    """Return the threads KD-tree builds and queries use."""
    return _threads


@contextmanager
def sharing_cores() -> Iterator[None]:
    """Run the GIL-free trees' queries of this thread on one thread.

    For a thread that runs beside another busy one (the two scans of a pair): each
    gets a core of its own instead of two OpenMP teams fighting for two cores.
    small_gicp's queries keep :func:`threads`: they hold the GIL, so the other
    thread waits for them anyway.
    """
    before = getattr(_local, "shared", False)
    _local.shared = True
    try:
        yield
    finally:
        _local.shared = before


# A query of less work than this (queries x (neighbours + 3), about 0.1 us each on one
# thread) runs on one thread whatever threads() says: waking the second OpenMP thread
# cost more than it saved on a loaded 2-core machine (6,000 nearest-point queries:
# 1.8 ms on one thread, 11.7 ms on two; 351 queries of 64 neighbours: 0.7 and 16 ms).
# The answers do not depend on the threads.
SMALL_BATCH = 100_000


def batch_threads(n_queries: int, k: int, threads: int | None = None) -> int:
    """Threads for ``n_queries`` queries of ``k`` neighbours (one for a small batch)."""
    n = _threads if threads is None else threads
    return n if n_queries * (k + 3) >= SMALL_BATCH else 1


def build_threads(n_points: int, threads: int | None = None) -> int:
    """Threads for building a tree on ``n_points`` points.

    One below 100,000 points: 2-3 ms on one thread, and a second thread cost up to
    25 ms of waiting on a loaded machine.
    """
    n = _threads if threads is None else threads
    return n if n_points >= 100_000 else 1


class Tree(Protocol):
    """A KD-tree on fixed points."""

    def knn(
        self, queries: np.ndarray, k: int, threads: int
    ) -> tuple[np.ndarray, np.ndarray]:
        """Return ``(idx, sq)``: (M, k) int64 indices and squared distances."""
        ...


class _SmallGicpTree:
    __slots__ = ("_tree",)

    def __init__(self, points: np.ndarray, threads: int) -> None:
        import small_gicp

        self._tree = small_gicp.KdTree(
            points, num_threads=build_threads(len(points), threads)
        )

    def knn(
        self, queries: np.ndarray, k: int, threads: int
    ) -> tuple[np.ndarray, np.ndarray]:
        idx, sq = self._tree.batch_knn_search(queries, k, num_threads=threads)
        # Every index is valid (k <= N): the uint64 array reads as int64, no copy.
        return idx.view(np.int64), sq


class _PyKdTree:
    __slots__ = ("_tree",)

    def __init__(self, points: np.ndarray) -> None:
        kd_tree, _ = _pykdtree()
        self._tree = kd_tree(points, leafsize=16)

    def knn(
        self, queries: np.ndarray, k: int, threads: int
    ) -> tuple[np.ndarray, np.ndarray]:
        _, set_threads_ = _pykdtree()
        # OpenMP's thread count is a per-thread setting: set it for this call.
        set_threads_(1 if getattr(_local, "shared", False) else threads)
        sq, idx = self._tree.query(queries, k=k, sqr_dists=True)
        return idx.astype(np.int64).reshape(-1, k), sq.reshape(-1, k)


def _no_threads(n: int) -> None:
    """Pykdtree built without OpenMP: one thread whatever is asked."""


@functools.cache
def _pykdtree() -> tuple[Any, Any]:
    """Return pykdtree's ``KDTree`` and its OpenMP ``omp_set_num_threads``.

    ``(None, None)`` when pykdtree does not import. The OpenMP library looked up is
    the one pykdtree's extension itself links (``dlsym`` on its handle searches its
    own dependencies first), not small_gicp's.
    """
    try:
        from pykdtree import kdtree
    except ImportError:
        return None, None
    setter: Callable[[int], None] = _no_threads
    try:
        found = ctypes.CDLL(kdtree.__file__).omp_set_num_threads
    except (OSError, AttributeError):
        pass
    else:
        found.argtypes, found.restype = [ctypes.c_int], None
        setter = found
    return kdtree.KDTree, setter


def build(points: np.ndarray, threads: int | None = None) -> Tree:
    """Build a tree on ``points`` ((N, 3) C-contiguous float64, N >= 1).

    ``threads``: for small_gicp's parallel build of a large tree; None:
    :func:`threads`.
    """
    n_threads = _threads if threads is None else threads
    if len(points) < PYKDTREE_MAX_POINTS and _pykdtree()[0] is not None:
        return _PyKdTree(points)
    return _SmallGicpTree(points, n_threads)
