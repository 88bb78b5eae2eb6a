"""Per-scan speed-ups against the answers they replaced: the shared neighbour table
against fresh queries (and brute force), and each stage with the table against the
same stage without it."""

from __future__ import annotations

import numpy as np
import pytest

from amrst.neighbours import NeighbourTable, knn
from amrst.params import RegistrationParams
from amrst.stages.preprocess import PreprocessParams, preprocess_points
from amrst.stages.separate import SeparateParams, separate_wood
from amrst.stages.skeleton import SkeletonParams, build_skeleton


def _brute_knn(xyz: np.ndarray, k: int, rows: np.ndarray) -> np.ndarray:
    d = np.linalg.norm(xyz[rows, None, :] - xyz[None, :, :], axis=2)
    return np.sort(d, axis=1)[:, :k]


def _cloud(n: int, seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    return rng.normal(size=(n, 3)) * [1.0, 1.0, 3.0]


@pytest.mark.parametrize("keep_fraction", [1.0, 0.97, 0.6, 0.1])
def test_table_subsets_give_the_fresh_query(keep_fraction: float) -> None:
    """Same indices and distances as a query on the subset, nested subsets too,
    whether the rows are read off the table or (too few left) queried again."""
    xyz = _cloud(6000, seed=int(keep_fraction * 100))
    rng = np.random.default_rng(5)
    table = NeighbourTable.build(xyz, 20)
    keep = np.flatnonzero(rng.random(len(xyz)) < keep_fraction)
    view = table.subset(keep)
    np.testing.assert_array_equal(view.xyz, xyz[keep])
    for k in (1, 8, 17, 20):
        rows = np.sort(rng.choice(len(keep), size=min(700, len(keep)), replace=False))
        d, i = view.knn(k, rows)
        d_ref, i_ref = knn(xyz[keep], k, xyz[keep][rows])
        np.testing.assert_array_equal(i, i_ref)
        np.testing.assert_array_equal(d, d_ref)
        np.testing.assert_allclose(d, _brute_knn(xyz[keep], k, rows), atol=1e-12)
    inner = np.flatnonzero(rng.random(len(keep)) < 0.7)
    d, i = view.subset(inner).knn(9)
    d_ref, i_ref = knn(xyz[keep][inner], 9)
    np.testing.assert_array_equal(i, i_ref)
    np.testing.assert_array_equal(d, d_ref)


def test_table_beyond_its_k_and_on_tiny_clouds() -> None:
    xyz = _cloud(500, seed=1)
    table = NeighbourTable.build(xyz, 5)
    _, i = table.knn(12)  # more than listed: a fresh query
    np.testing.assert_array_equal(i, knn(xyz, 12)[1])
    np.testing.assert_array_equal(table.knn(3)[1], knn(xyz, 3)[1])
    tiny = NeighbourTable.build(xyz[:4], 30)  # k capped at the points
    assert tiny.k == 4
    np.testing.assert_array_equal(
        tiny.subset(np.array([0, 2, 3])).knn(3)[1][:, 0], [0, 1, 2]
    )
    with pytest.raises(ValueError, match="k must be"):
        tiny.subset(np.array([1, 2])).knn(3)


def _tree_cloud(seed: int) -> np.ndarray:
    """A trunk, two branches and a sparse crown with outliers, 3 cm thinned."""
    rng = np.random.default_rng(seed)
    trunk = np.column_stack(
        [
            0.15 * np.cos(a := rng.uniform(0, 2 * np.pi, 6000)),
            0.15 * np.sin(a),
            rng.uniform(0, 4, 6000),
        ]
    )
    t = rng.uniform(0, 1, (2, 2000))
    branches = [
        np.column_stack([s * 2.0 * d, 0.05 * rng.normal(size=2000), 4 + 2.0 * s])
        for s, d in zip(t, (-1, 1), strict=True)
    ]
    crown = rng.normal(size=(5000, 3)) * [1.5, 1.5, 1.0] + [0, 0, 6.5]
    noise = rng.uniform(-4, 4, (60, 3)) + np.array([0, 0, 4])
    return np.vstack([trunk, *branches, crown, noise])


@pytest.mark.parametrize("seed", [0, 1])
def test_stages_read_the_same_neighbours_off_the_table(seed: int) -> None:
    """Preprocess, separation and skeleton: identical results with the shared table."""
    xyz = _tree_cloud(seed)
    pp = PreprocessParams()
    plain = preprocess_points(xyz, pp)
    shared = preprocess_points(xyz, pp, share_k=32)
    assert plain.neighbours is None
    assert shared.neighbours is not None
    np.testing.assert_array_equal(shared.index, plain.index)
    assert len(shared.neighbours) == len(shared.xyz)
    np.testing.assert_array_equal(shared.neighbours.xyz, shared.xyz)
    # A scene-like cut, then the stages on what is left.
    keep = np.flatnonzero(shared.xyz[:, 2] > 0.4)
    pts, table = shared.xyz[keep], shared.neighbours.subset(keep)
    sp = SeparateParams()
    a, b = separate_wood(pts, None, sp), separate_wood(pts, None, sp, neighbours=table)
    np.testing.assert_array_equal(a.is_wood, b.is_wood)
    np.testing.assert_array_equal(a.wood_score, b.wood_score)
    assert 0.05 < a.wood_fraction < 0.95
    kp = SkeletonParams()
    s1, s2 = build_skeleton(pts, kp), build_skeleton(pts, kp, neighbours=table)
    np.testing.assert_array_equal(s1.nodes, s2.nodes)
    np.testing.assert_array_equal(s1.parent, s2.parent)
    assert len(s1.nodes) > 10


def test_analysis_shares_one_query_per_scan(tiny_tree) -> None:
    """prepare_scan + skeletonise_scan query the KD-tree once when nothing falls back;
    the results equal the stages run on their own."""
    import amrst.neighbours as nb
    from amrst.pipeline import analyse_scan

    params = RegistrationParams()
    calls: list[tuple[int, int]] = []
    real = nb.knn

    def counting(points, k, queries=None, threads=1):  # type: ignore[no-untyped-def]
        calls.append((len(points), k))
        return real(points, k, queries, threads)

    nb.knn = counting
    try:
        an = analyse_scan(tiny_tree, params)
    finally:
        nb.knn = real
    assert calls[0][1] >= 30  # the shared query
    alone = separate_wood(an.xyz, None, params.separate)
    np.testing.assert_array_equal(alone.is_wood, an.is_wood)
    skel = build_skeleton(an.xyz, params.skeleton)
    np.testing.assert_array_equal(skel.nodes, an.skeleton.nodes)
