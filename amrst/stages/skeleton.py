"""Tree skeleton from wood points: graph, shortest paths from the root, centralisation.

Paper section II.C (Delaunay graph, Dijkstra, geometric centralisation), in the form of
Xu et al. (2007): a k-nearest-neighbour graph on the wood points (gaps left by occlusion
bridged by the shortest Delaunay edges between components), geodesic distances from the
root by Dijkstra (scipy.sparse.csgraph), points binned by geodesic distance, each
connected cluster of a bin becomes one skeleton node at its centroid, and its parent is
the cluster its shortest paths come from. Short twigs are pruned.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import TYPE_CHECKING, cast

import numpy as np

from amrst.errors import InvalidInput
from amrst.progress import NULL_REPORTER, Reporter

if TYPE_CHECKING:
    import numpy.typing as npt
    from scipy.sparse import csr_matrix

    from amrst.neighbours import NeighbourTable


@dataclass(frozen=True, slots=True, kw_only=True)
class SkeletonParams:
    """Skeleton extraction settings."""

    points: str = field(
        default="all",
        metadata={
            "choices": ("wood", "all"),
            "help": "Skeletonise the wood points (the paper) or all points; falls back to all when too few wood points.",
        },
    )
    voxel_size_m: float = field(
        default=0.04,
        metadata={
            "unit": "m",
            "min": 0.005,
            "max": 0.5,
            "help": "Wood points are thinned to this voxel size before the graph is built. Typical 0.02-0.08.",
        },
    )
    neighbours: int = field(
        default=8,
        metadata={
            "unit": "points",
            "min": 3,
            "max": 50,
            "help": "k of the k-nearest-neighbour graph.",
        },
    )
    max_edge_m: float = field(
        default=0.25,
        metadata={
            "unit": "m",
            "min": 0.01,
            "max": 5.0,
            "help": "Longest graph edge between neighbours; longer gaps are bridged once per component. Typical 3-6 voxels.",
        },
    )
    bin_size_m: float = field(
        default=0.25,
        metadata={
            "unit": "m",
            "min": 0.02,
            "max": 5.0,
            "help": "Width of the geodesic-distance bins; one skeleton node per connected cluster of a bin. Typical 0.1-0.5.",
        },
    )
    root_slice_m: float = field(
        default=0.3,
        metadata={
            "unit": "m",
            "min": 0.01,
            "max": 5.0,
            "help": "Height above the lowest wood point in which the trunk base (root) is looked for.",
        },
    )
    prune_length_m: float = field(
        default=0.6,
        metadata={
            "unit": "m",
            "min": 0.0,
            "max": 10.0,
            "help": "Twigs (end branches) shorter than this are removed; repeated twice. Typical 2-3 bins.",
        },
    )
    min_points: int = field(
        default=50,
        metadata={
            "unit": "points",
            "min": 10,
            "max": 100000,
            "help": "Fewest wood points from which a skeleton is built.",
        },
    )

    def __post_init__(self) -> None:
        if min(self.voxel_size_m, self.max_edge_m, self.bin_size_m) <= 0:
            raise ValueError("skeleton sizes must be > 0")


@dataclass(frozen=True, slots=True)
class SkeletonResult:
    """A rooted tree of skeleton nodes."""

    nodes: np.ndarray  # (K, 3) float64 node positions (local coordinates)
    parent: np.ndarray  # (K,) int64 parent node, -1 for the root
    geodesic_m: np.ndarray  # (K,) float64 path length from the root along the wood
    n_points: np.ndarray  # (K,) int64 wood points in each node's cluster
    root: int
    n_components_bridged: int

    @property
    def edges(self) -> np.ndarray:
        """(K-1, 2) int64 (parent, child) pairs."""
        child = np.flatnonzero(self.parent >= 0)
        return np.column_stack([self.parent[child], child])

    @property
    def children_count(self) -> np.ndarray:
        """(K,) number of children of each node."""
        p = self.parent[self.parent >= 0]
        return np.bincount(p, minlength=len(self.nodes))


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


def _graph(
    xyz: np.ndarray, params: SkeletonParams, table: NeighbourTable | None = None
) -> tuple[csr_matrix, int]:
    """Sparse symmetric graph: kNN edges plus the shortest bridges between components.

    Gaps left by occlusion split the wood into components. Candidate bridges are the
    longer edges of a wider kNN query; a minimum spanning tree over components keeps
    the shortest set that links them (the paper's Delaunay graph links everything, at
    several times the cost). Components still apart are linked to the root's one by
    their nearest point. A bridge costs twice its length, so paths prefer real wood.
    """
    from scipy.sparse import coo_matrix, csr_matrix
    from scipy.sparse.csgraph import connected_components, minimum_spanning_tree

    from amrst.neighbours import NearestTree, knn

    n = len(xyz)
    k = min(max(params.neighbours, 16) + 1, n)
    dist, idx = knn(xyz, k) if table is None else table.knn(k)
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
        # flatnonzero and divmod: np.nonzero's (row, column) order, 10x faster.
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
            n_comp, labels = _merge_components(labels, n_comp, a, b)
        if n_comp > 1:
            # Far islands: link each to the largest component by its nearest point.
            main = np.argmax(np.bincount(labels))
            main_idx = np.flatnonzero(labels == main)
            # One thread: a tree of a few thousand points, where a second OpenMP
            # thread cost more than it gave (1.0 s against 0.4 s over the 43 scans
            # with far islands, this loaded 2-core machine; the same answers).
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


def _merge_components(
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


def _bin_clusters(graph: csr_matrix, b: np.ndarray, max_edge: float) -> np.ndarray:
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


def _find_root(xyz: np.ndarray, slice_m: float) -> int:
    low = xyz[:, 2] < xyz[:, 2].min() + slice_m
    centre = np.median(xyz[low, :2], axis=0)
    cand = np.flatnonzero(low)
    return int(cand[np.argmin(np.sum((xyz[cand, :2] - centre) ** 2, axis=1))])


def _prune(parent: np.ndarray, length: np.ndarray, min_len: float) -> np.ndarray:
    """Mask of nodes kept after removing end chains shorter than ``min_len``."""
    keep = np.ones(len(parent), dtype=bool)
    for _ in range(2):
        children = np.bincount(parent[(parent >= 0) & keep], minlength=len(parent))
        ends = np.flatnonzero(keep & (children == 0) & (parent >= 0))
        for end in ends:
            chain, node, total = [], end, 0.0
            while (
                node >= 0 and keep[node] and children[node] <= 1 and parent[node] >= 0
            ):
                chain.append(node)
                total += length[node]
                node = parent[node]
            # node is now a branch point (or root): the chain is a twig hanging off it.
            if total < min_len and node >= 0 and children[node] >= 2:
                keep[chain] = False
                children[node] -= 1
    return keep


def build_skeleton(
    wood_xyz: np.ndarray,
    params: SkeletonParams,
    reporter: Reporter = NULL_REPORTER,
    neighbours: NeighbourTable | None = None,
) -> SkeletonResult:
    """Skeletonise a wood point cloud.

    Parameters
    ----------
    wood_xyz : (N, 3) float64
        Wood points (local coordinates), z up.
    params : SkeletonParams
    reporter : Reporter
    neighbours : NeighbourTable or None
        The neighbours of exactly ``wood_xyz`` (the preprocess query): the graph's
        are read off it instead of a new query; the same skeleton.

    Returns
    -------
    SkeletonResult

    Raises
    ------
    InvalidInput
        When there are fewer than ``params.min_points`` wood points.
    """
    from scipy.sparse.csgraph import dijkstra

    from amrst.stages.voxels import voxel_sample

    if len(wood_xyz) < params.min_points:
        raise InvalidInput(
            f"Only {len(wood_xyz)} wood points: at least {params.min_points} are needed for a "
            "skeleton. Try separation mode 'geometry' or 'all_wood', or a smaller voxel size."
        )
    sample = voxel_sample(wood_xyz, params.voxel_size_m)
    xyz = wood_xyz[sample]
    table = None
    if neighbours is not None and len(neighbours) == len(wood_xyz):
        table = neighbours.subset(sample)
    graph, bridged = _graph(xyz, params, table)
    reporter.progress(0.3, "graph built")
    reporter.check_cancelled()
    root = _find_root(xyz, params.root_slice_m)
    geo, pred = dijkstra(graph, indices=root, return_predecessors=True)
    reach = np.isfinite(geo)
    reporter.progress(0.6, "shortest paths")
    reporter.check_cancelled()
    # Bin by geodesic distance; clusters = components of within-bin edges.
    b = np.where(
        reach, np.floor(np.where(reach, geo, 0) / params.bin_size_m), -1
    ).astype(np.int64)
    cluster = _bin_clusters(graph, b, params.max_edge_m)
    k = int(cluster.max()) + 1
    valid = cluster >= 0
    counts = np.bincount(cluster[valid], minlength=k)
    # np.bincount with weights gives float64 (numpy's stubs say intp).
    nodes = cast(
        "npt.NDArray[np.float64]",
        np.column_stack(
            [np.bincount(cluster[valid], xyz[valid, d], k) for d in range(3)]
        ),
    )
    nodes /= np.maximum(counts, 1)[:, None]
    node_geo = np.full(k, np.inf)
    np.minimum.at(node_geo, cluster[valid], geo[valid])
    # Parent: the cluster the shortest paths come from (majority over the cluster's points).
    pts = np.flatnonzero(valid & (pred >= 0))
    pc, cc = cluster[pred[pts]], cluster[pts]
    cross = (pc != cc) & (pc >= 0)
    parent = np.full(k, -1, dtype=np.int64)
    if cross.any():
        # (child, parent) cluster pairs as one code: a 1-D unique, same order.
        codes, votes = np.unique(
            cc[cross].astype(np.int64) * k + pc[cross], return_counts=True
        )
        pairs = np.column_stack([codes // k, codes % k])
        order = np.lexsort((-votes, pairs[:, 0]))
        first = np.r_[True, pairs[order][1:, 0] != pairs[order][:-1, 0]]
        best = pairs[order][first]
        parent[best[:, 0]] = best[:, 1]
    root_node = int(cluster[root])
    parent[root_node] = -1
    # Cycles cannot occur: parents have strictly smaller geodesic distance (shortest paths).
    seg = np.where(
        parent >= 0, np.linalg.norm(nodes - nodes[np.maximum(parent, 0)], axis=1), 0.0
    )
    keep = _prune(parent, seg, params.prune_length_m)
    reporter.progress(0.9, "pruned")
    return _compact(nodes, parent, node_geo, counts, keep, root_node, bridged)


def _compact(
    nodes: np.ndarray,
    parent: np.ndarray,
    geo: np.ndarray,
    counts: np.ndarray,
    keep: np.ndarray,
    root: int,
    bridged: int,
) -> SkeletonResult:
    new_id = np.full(len(nodes), -1, dtype=np.int64)
    new_id[keep] = np.arange(int(keep.sum()))
    par = parent[keep]
    par = np.where(par >= 0, new_id[np.maximum(par, 0)], -1)
    return SkeletonResult(
        nodes[keep], par, geo[keep], counts[keep], int(new_id[root]), bridged
    )
