"""The skeleton's graph on the wood points, and the clusters its nodes come from.

Split from ``skeleton.py`` (which keeps the parameters, the result and the stage):
:func:`wood_graph` builds the k-nearest-neighbour graph with the bridges that join the
components gaps left apart, :func:`bin_clusters` the connected clusters of a
geodesic-distance bin.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from amrst.neighbours import THREADS

if TYPE_CHECKING:
    from scipy.sparse import csr_matrix

    from amrst.neighbours import NeighbourTable
    from amrst.stages.skeleton import SkeletonParams


def _min_edge_per_pair(
    key: np.ndarray, el: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Index of the shortest edge for each component pair code, by ascending code.

    Returns the edge indices and their codes.
    """
    order = np.lexsort((el, key))
    sorted_key = key[order]
    first = np.r_[True, sorted_key[1:] != sorted_key[:-1]]
    return order[first], sorted_key[first]


def wood_graph(
    xyz: np.ndarray,
    params: SkeletonParams,
    table: NeighbourTable | None = None,
    threads: int = THREADS,
) -> tuple[csr_matrix, int]:
    """Sparse symmetric graph: kNN edges plus the shortest bridges between components.

    Gaps left by occlusion split the wood into components. Candidate bridges are the
    longer edges of a wider kNN query; a minimum spanning tree over components keeps
    the shortest set that links them (the paper's Delaunay graph links everything, at
    several times the cost). Components still apart are linked to the root's one by
    their nearest point. A bridge costs twice its length, so paths prefer real wood.
    ``threads``: for the kNN query when there is no ``table``.
    """
    from scipy.sparse import coo_matrix, csr_matrix
    from scipy.sparse.csgraph import connected_components, minimum_spanning_tree

    from amrst.neighbours import NearestTree, knn

    n = len(xyz)
    k = min(max(params.neighbours, 16) + 1, n)
    dist, idx = knn(xyz, k, threads=threads) if table is None else table.knn(k)
    kn = min(params.neighbours + 1, n)
    # The kNN edges row by row: built as CSR straight away (rows are in order).
    ok = dist[:, 1:kn] <= params.max_edge_m
    per_row = np.count_nonzero(ok, axis=1)
    cols, w = idx[:, 1:kn][ok], dist[:, 1:kn][ok]
    rows = np.repeat(np.arange(n), per_row)
    indptr = np.zeros(n + 1, dtype=np.int64)
    np.cumsum(per_row, out=indptr[1:])
    g = csr_matrix((w, cols, indptr), shape=(n, n))
    n_comp, labels = connected_components(g, directed=False)
    bridged = 0
    if n_comp > 1:
        cross = labels[idx[:, 1:]] != labels[:, None]
        cross &= np.isfinite(dist[:, 1:])
        # flatnonzero and divmod: np.nonzero's (row, column) order, faster.
        e0, c = np.divmod(np.flatnonzero(cross), cross.shape[1])
        c += 1
        e1, el = idx[e0, c], dist[e0, c]
        if len(e0):
            la, lb = labels[e0].astype(np.int64), labels[e1].astype(np.int64)
            # One code per unordered component pair.
            sel, sel_key = _min_edge_per_pair(
                np.minimum(la, lb) * n_comp + np.maximum(la, lb), el
            )
            comp = coo_matrix(
                (el[sel] + 1e-9, (la[sel], lb[sel])), shape=(n_comp, n_comp)
            )
            mst = minimum_spanning_tree(comp).tocoo()
            # Map each MST component pair back to its shortest edge.
            a, b = mst.row.astype(np.int64), mst.col.astype(np.int64)
            key = np.minimum(a, b) * n_comp + np.maximum(a, b)
            bridges = sel[np.searchsorted(sel_key, key)]
            rows, cols, w = (
                np.r_[rows, e0[bridges]],
                np.r_[cols, e1[bridges]],
                np.r_[w, 2.0 * el[bridges]],
            )
            bridged += len(bridges)
            # Components after bridging: those of the small graph of bridged
            # components, numbered like connected_components numbers the points'
            # (by their first point).
            n_comp, labels = merge_components(labels, n_comp, a, b)
        if n_comp > 1:
            # Far islands: link each to the largest component by its nearest point.
            main = np.argmax(np.bincount(labels))
            main_idx = np.flatnonzero(labels == main)
            # One thread: on a tree of a few thousand points a second OpenMP thread
            # costs more than it gives (the answers are the same).
            main_tree = NearestTree(xyz[main_idx], threads=1)
            others = np.flatnonzero(labels != main)
            d, j = main_tree.query(xyz[others])
            lab = labels[others]
            order = np.lexsort((d, lab))
            first = order[np.r_[True, lab[order][1:] != lab[order][:-1]]]
            rows = np.r_[rows, others[first]]
            cols = np.r_[cols, main_idx[j[first]]]
            w = np.r_[w, 2.0 * d[first]]
            bridged += len(first)
    g = coo_matrix((w, (rows, cols)), shape=(n, n)).tocsr()
    return g.maximum(g.T), bridged


def merge_components(
    labels: np.ndarray, n_comp: int, a: np.ndarray, b: np.ndarray
) -> tuple[int, np.ndarray]:
    """Components of the points once components ``a[i]`` and ``b[i]`` are linked.

    Numbered as scipy's connected_components numbers them on the linked point
    graph: in the order of each component's first point.
    """
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    links = coo_matrix((np.ones(len(a)), (a, b)), shape=(n_comp, n_comp))
    m, merged = connected_components(links, directed=False)
    point_labels = merged[labels]
    _, first = np.unique(point_labels, return_index=True)
    rank = np.empty(m, dtype=np.int64)
    rank[np.argsort(first)] = np.arange(m)
    return int(m), rank[point_labels].astype(labels.dtype)


def bin_clusters(graph: csr_matrix, b: np.ndarray, max_edge: float) -> np.ndarray:
    """Cluster of each point: components of the short edges within a geodesic bin.

    ``b`` is each point's bin (-1 unreached). Clusters are numbered from 0 in the
    order of their first point, unreached points -1. The edges are read off the
    graph's CSR arrays (canonical: rows in order, columns sorted) into a CSR matrix
    directly, without the COO conversion and its sort; the labels do not depend on
    the edge order, scipy numbers components by their first point.
    """
    from scipy.sparse import csr_matrix
    from scipy.sparse.csgraph import connected_components

    n = graph.shape[0]
    row = np.repeat(np.arange(n), np.diff(graph.indptr))
    col = graph.indices
    br = b[row]
    same = (br == b[col]) & (br >= 0) & (graph.data <= max_edge)
    indptr = np.zeros(n + 1, dtype=np.int64)
    np.cumsum(np.bincount(row[same], minlength=n), out=indptr[1:])
    sub = csr_matrix((np.ones(int(indptr[-1])), col[same], indptr), shape=(n, n))
    m, cluster = connected_components(sub, directed=False)
    # Renumber the reached ones 0.. in the same order (np.unique's inverse).
    cluster = np.where(b >= 0, cluster, -1)
    present = np.zeros(m + 1, dtype=bool)
    present[cluster + 1] = True
    rank = np.cumsum(present) - 1 - int(present[0])
    return np.asarray(rank[cluster + 1])
