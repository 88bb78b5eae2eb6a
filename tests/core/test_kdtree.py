"""The two KD-tree libraries behind amrst.kdtree: brute-force answers from both,
the size that picks one or the other, and the thread count of the GIL-free one."""

from __future__ import annotations

import threading

import numpy as np
import pytest

from amrst import kdtree


def _brute(points: np.ndarray, queries: np.ndarray, k: int) -> np.ndarray:
    d2 = ((queries[:, None, :] - points[None, :, :]) ** 2).sum(axis=2)
    return np.sort(d2, axis=1)[:, :k]


@pytest.fixture(params=["pykdtree", "small_gicp"])
def backend(request: pytest.FixtureRequest, monkeypatch: pytest.MonkeyPatch) -> str:
    if request.param == "small_gicp":
        monkeypatch.setattr(kdtree, "PYKDTREE_MAX_POINTS", 0)
    return str(request.param)


@pytest.mark.parametrize(("n", "k"), [(1, 1), (7, 7), (500, 1), (3000, 12)])
def test_every_tree_gives_the_brute_force_neighbours(
    backend: str, n: int, k: int
) -> None:
    rng = np.random.default_rng(n)
    pts = np.round(rng.uniform(0, 1, (n, 3)), 3)  # mm grid: ties occur
    queries = rng.uniform(0, 1, (200, 3))
    tree = kdtree.build(pts)
    assert type(tree).__name__ == (
        "_PyKdTree" if backend == "pykdtree" else "_SmallGicpTree"
    )
    for threads in (1, 2):
        idx, sq = tree.knn(queries, k, threads)
        assert idx.dtype == np.int64
        assert idx.shape == sq.shape == (len(queries), k)
        np.testing.assert_allclose(sq, _brute(pts, queries, k), rtol=1e-12, atol=1e-15)
        # the index names a point at that distance (ties may be listed in any order)
        got = ((pts[idx] - queries[:, None, :]) ** 2).sum(axis=2)
        np.testing.assert_allclose(got, sq, rtol=1e-12, atol=1e-15)


def test_the_gil_free_tree_answers_alike_beside_another_thread() -> None:
    """sharing_cores: one OpenMP thread per query in this thread only; the answers
    are the same, and another thread keeps its own setting."""
    rng = np.random.default_rng(5)
    pts = rng.uniform(0, 1, (20_000, 3))
    tree = kdtree.build(pts)
    alone = tree.knn(pts, 10, 2)
    seen: list[bool] = []

    def other() -> None:
        seen.append(getattr(kdtree._local, "shared", False))

    with kdtree.sharing_cores():
        assert kdtree._local.shared
        shared = tree.knn(pts, 10, 2)
        t = threading.Thread(target=other)
        t.start()
        t.join()
    assert not getattr(kdtree._local, "shared", False)
    assert seen == [False]
    np.testing.assert_array_equal(alone[1], shared[1])
    np.testing.assert_array_equal(alone[0], shared[0])


def test_pykdtree_is_found_with_its_own_openmp() -> None:
    """The OpenMP setter is pykdtree's own (its wheel links a copy of libgomp)."""
    tree_cls, setter = kdtree._pykdtree()
    assert tree_cls is not None
    setter(1)  # callable; a no-op stand-in when pykdtree has no OpenMP
    assert kdtree.build(np.zeros((3, 3))).__class__.__name__ == "_PyKdTree"
    big = kdtree.build(
        np.random.default_rng(0).uniform(size=(kdtree.PYKDTREE_MAX_POINTS, 3))
    )
    assert big.__class__.__name__ == "_SmallGicpTree"
