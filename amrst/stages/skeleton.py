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
from amrst.neighbours import THREADS
from amrst.progress import NULL_REPORTER, Reporter
from amrst.stages.skeleton_graph import bin_clusters, wood_graph

if TYPE_CHECKING:
    import numpy.typing as npt

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
    *,
    threads: int = THREADS,
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
    threads : int
        Threads for a new neighbour query.

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
    graph, bridged = wood_graph(xyz, params, table, threads)
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
    cluster = bin_clusters(graph, b, params.max_edge_m)
    k = int(cluster.max()) + 1
    valid = cluster >= 0
    cv, xv = cluster[valid], xyz[valid]  # gathered once for the sums below
    counts = np.bincount(cv, minlength=k)
    # np.bincount with weights gives float64 (numpy's stubs say intp).
    nodes = cast(
        "npt.NDArray[np.float64]",
        np.column_stack([np.bincount(cv, xv[:, d], k) for d in range(3)]),
    )
    nodes /= np.maximum(counts, 1)[:, None]
    node_geo = np.full(k, np.inf)
    np.minimum.at(node_geo, cv, geo[valid])
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
    return _compact(
        nodes, parent, node_geo, counts, keep, root=root_node, bridged=bridged
    )


def _compact(
    nodes: np.ndarray,
    parent: np.ndarray,
    geo: np.ndarray,
    counts: np.ndarray,
    keep: np.ndarray,
    *,
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
