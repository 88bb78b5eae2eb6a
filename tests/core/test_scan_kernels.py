"""Per-scan kernels against reference answers: the shared neighbour table against
fresh queries (and brute force), and each stage with the table against the same stage
without it."""

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
    assert 0.05 < a.wood_fraction < 0.95
    kp = SkeletonParams()
    s1, s2 = build_skeleton(pts, kp), build_skeleton(pts, kp, neighbours=table)
    np.testing.assert_array_equal(s1.nodes, s2.nodes)
    np.testing.assert_array_equal(s1.parent, s2.parent)
    assert len(s1.nodes) > 10


def test_analysis_shares_one_query_per_scan(tiny_tree) -> None:
    """After the preprocess query, prepare_scan + skeletonise_scan build no KD-tree of
    their own (rows left short ask the cloud's tree); the results equal the stages
    run on their own."""
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
    assert calls == []
    assert an.pre.neighbours is not None
    assert an.pre.neighbours.k >= 30
    alone = separate_wood(an.xyz, None, params.separate)
    np.testing.assert_array_equal(alone.is_wood, an.is_wood)
    skel = build_skeleton(an.xyz, params.skeleton)
    np.testing.assert_array_equal(skel.nodes, an.skeleton.nodes)


def _reference_lowest(xyz: np.ndarray, cell_m: float) -> np.ndarray:
    """fit_ground's lowest point per cell before (unique + lexsort), kept verbatim."""
    ij = np.floor(xyz[:, :2] / cell_m).astype(np.int64)
    ij -= ij.min(axis=0)
    code = ij[:, 0] * (int(ij[:, 1].max()) + 1) + ij[:, 1]
    _, inv = np.unique(code, return_inverse=True)
    order = np.lexsort((xyz[:, 2], inv))
    return order[np.r_[0, np.flatnonzero(np.diff(inv[order])) + 1]]


def _reference_ransac(A, z, tol, max_slope, iterations, seed):  # type: ignore[no-untyped-def]
    """The loop _ransac_plane was (kept verbatim)."""
    rng = np.random.default_rng(seed)
    best_score, best = -np.inf, np.array([0.0, 0.0, float(np.min(z))])
    for idx in rng.integers(0, len(z), size=(iterations, 3)):
        try:
            coef = np.linalg.solve(A[idx], z[idx])
        except np.linalg.LinAlgError:
            continue
        if np.hypot(coef[0], coef[1]) > max_slope:
            continue
        r = z - A @ coef
        score = np.sum(np.abs(r) < tol) - 3.0 * np.sum(r < -2 * tol)
        if score > best_score:
            best_score, best = score, coef
    return best


def _ground_scene(seed: int) -> np.ndarray:
    """A sloped, bumpy ground on a mm grid (ties in height and on cell edges), with
    a stem and crown above it."""
    rng = np.random.default_rng(seed)
    xy = np.round(rng.uniform(-6, 6, (30_000, 2)), 3)
    z = (
        0.1 * xy[:, 0]
        + 0.05 * np.sin(xy[:, 1])
        + np.round(rng.normal(0, 0.01, len(xy)), 3)
    )
    tree = np.column_stack([rng.normal(0, 0.2, (4000, 2)), rng.uniform(0, 8, 4000)])
    return np.vstack([np.column_stack([xy, z]), tree])


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_lowest_point_per_cell_equals_the_lexsort(seed: int) -> None:
    from amrst.stages.ground import _lowest_per_cell

    xyz = _ground_scene(seed)
    xyz = np.vstack([xyz, xyz[:500]])  # exact duplicates: ties go to the lowest index
    for cell in (0.5, 0.25, 1.0):
        np.testing.assert_array_equal(
            _lowest_per_cell(xyz, cell), _reference_lowest(xyz, cell)
        )


@pytest.mark.parametrize("n_cells", [5, 60, 900])
def test_batched_ransac_equals_the_loop(n_cells: int) -> None:
    """Same plane, singular draws (a cell drawn twice) and steep planes included."""
    from amrst.stages.ground import _ransac_plane

    rng = np.random.default_rng(n_cells)
    xy = rng.uniform(-5, 5, (n_cells, 2))
    z = 0.2 * xy[:, 0] + rng.normal(0, 0.05, n_cells)
    z[: n_cells // 3] += rng.uniform(0.5, 3, n_cells // 3)  # crown points above
    A = np.column_stack([xy, np.ones(n_cells)])
    for slope in (0.05, 0.36, 10.0):
        got = _ransac_plane(A, z, 0.15, slope, 300, seed=3)
        np.testing.assert_array_equal(got, _reference_ransac(A, z, 0.15, slope, 300, 3))


@pytest.mark.parametrize("seed", [0, 1])
def test_nearest_cell_equals_the_kd_tree(seed: int) -> None:
    """Grid lookup against cKDTree: points on cell edges and in empty cells too."""
    from scipy.spatial import cKDTree

    from amrst.stages.ground import fit_ground

    xyz = _ground_scene(seed)
    fit = fit_ground(
        xyz,
        cell_m=0.5,
        tol_m=0.15,
        max_slope_deg=20,
        min_area_m2=4,
        iterations=300,
        seed=0,
    )
    assert fit.found
    rng = np.random.default_rng(seed)
    q = np.vstack(
        [
            xyz[::3],
            rng.uniform(-9, 9, (3000, 3)),  # outside the grid and in empty cells
            np.column_stack(
                [np.round(rng.uniform(-6, 6, (2000, 2)) * 2) / 2, np.zeros(2000)]
            ),
        ]
    )
    got = fit.nearest_cell(q)
    want = cKDTree(fit.centres).query(q[:, :2])[1]
    d_got = np.linalg.norm(fit.centres[got] - q[:, :2], axis=1)
    d_want = np.linalg.norm(fit.centres[want] - q[:, :2], axis=1)
    np.testing.assert_allclose(d_got, d_want, rtol=0, atol=1e-12)
    # Off the cell edges (every scan point here) the very same cell.
    np.testing.assert_array_equal(got[: len(xyz[::3])], want[: len(xyz[::3])])
    assert np.mean(got == want) > 0.99


def test_pair_lengths_equal_the_norm_bit_for_bit() -> None:
    from amrst.stages.stems import _pair_lengths

    rng = np.random.default_rng(4)
    pts = np.round(rng.normal(size=(3000, 3)) * 5, 3)
    pairs = rng.integers(0, len(pts), (50_000, 2))
    want = np.linalg.norm(pts[pairs[:, 0]] - pts[pairs[:, 1]], axis=1)
    np.testing.assert_array_equal(_pair_lengths(pts, pairs), want)
    assert len(_pair_lengths(pts, np.zeros((0, 2), dtype=np.int64))) == 0


@pytest.mark.parametrize("seed", [0, 1, 2, 3])
def test_merged_components_equal_scipys_on_the_linked_graph(seed: int) -> None:
    """Same labels, same numbering, as connected_components on the point graph with
    one edge per component link added (what the skeleton graph did before)."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    from amrst.stages.skeleton_graph import merge_components

    rng = np.random.default_rng(seed)
    n = 3000
    e = rng.integers(0, n, (2200, 2))
    g = coo_matrix((np.ones(len(e)), (e[:, 0], e[:, 1])), shape=(n, n))
    n_comp, labels = connected_components(g, directed=False)
    links = rng.integers(0, n_comp, (n_comp // 2, 2))
    # One point of each linked component stands for it in the point graph.
    first_point = np.array([np.flatnonzero(labels == c)[-1] for c in range(n_comp)])
    linked = coo_matrix(
        (
            np.ones(len(e) + len(links)),
            (
                np.r_[e[:, 0], first_point[links[:, 0]]],
                np.r_[e[:, 1], first_point[links[:, 1]]],
            ),
        ),
        shape=(n, n),
    )
    want_n, want = connected_components(linked, directed=False)
    got_n, got = merge_components(labels, n_comp, links[:, 0], links[:, 1])
    assert got_n == want_n < n_comp
    np.testing.assert_array_equal(got, want)
