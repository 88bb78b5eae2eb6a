"""Which tree each point above the ground belongs to, and how tall each tree is.

Every point goes to the stem it reaches at the least cost through neighbouring points
(one point per 5 cm voxel); a metre across costs more than a metre up. A crown seen
from two positions breaks into pieces where one side is hidden and the other out of
range, so a path may also jump a gap: links up to ``GAPS`` long join points above the
crown height, and cost their length times a factor that grows with the gap. A chain
of small gaps thus beats one long jump, and a piece of crown goes with the crown it
continues rather than with the nearest tree. A stem's seeds include the stem
followed up above its circles (``stemmap._trace_stem``), each at the cost of the
climb to it: a stem hidden for a metre by a neighbour's crown no longer costs a gap,
which would hand its top to the neighbour. Pieces no path reaches (a tree whose
stem was not found, beyond every gap) belong to no tree.

This is not ``stages/stems.assign_to_stems`` (the scene stage of a registration,
which must not change): that gives every unreached piece above the crown height to
the nearest reached point one point at a time, which hands the pieces of a big crown
over a small tree to the small tree.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from amrst.stages.voxels import voxel_representatives

if TYPE_CHECKING:
    from collections.abc import Sequence

#: Voxel of the path graph (m): one node per voxel.
NODE_VOXEL_M = 0.05
#: (longest link (m), cost per metre) of each kind of link: neighbouring points, then
#: gaps in a crown. The gap links join one node per voxel of a third of their length.
GAPS = ((0.15, 1.0), (0.45, 3.0), (2.0, 10.0))
#: A link's horizontal metres cost this many vertical ones: a tree grows up, so the
#: top of a tall crown under a broad one goes with the stem it rises from, not with
#: the broad crown that reaches across to it.
ACROSS_COST = 2.0


def assign_crowns(
    xyz: np.ndarray,
    h: np.ndarray,
    above: np.ndarray,
    seeds: Sequence[np.ndarray],
    crown_height_m: float,
    start: Sequence[np.ndarray] | None = None,
) -> np.ndarray:
    """Stem number of every point (the index of its seed), -1 for none.

    Parameters
    ----------
    xyz : (N, 3) float64
    h : (N,) float64
        Height of each point above the ground (m).
    above : (M,) int64
        The points above the ground (indices into ``xyz``); the others get -1.
    seeds : sequence of (K,) int64
        Each stem's points (indices into ``xyz``, among ``above``); where two share a
        voxel, the first stem keeps it.
    crown_height_m : float
        Gap links join points higher than this only: a shrub beside a stem stays
        apart.
    start : sequence of (K,) float64, or None
        The cost each seed point's path starts at (None: all 0): a point of a stem
        followed up starts at the cost of climbing the stem to it, and so gains its
        stem no crown an unbroken stem would not.

    Returns
    -------
    (N,) int64
    """
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import dijkstra

    owner = np.full(len(xyz), -1, dtype=np.int64)
    if not len(above) or not len(seeds):
        return owner
    reps, node_of = voxel_representatives(xyz[above], NODE_VOXEL_M)
    nodes = xyz[above][reps]
    crown = h[above][reps] > crown_height_m
    rows, cols, cost = [], [], []
    shorter = 0.0
    for link, per_m in GAPS:
        i, j, length = _links(nodes, crown, link, shorter, first=shorter == 0.0)
        rows.append(i)
        cols.append(j)
        cost.append(length * per_m)
        shorter = link
    graph = coo_matrix(
        (np.concatenate(cost), (np.concatenate(rows), np.concatenate(cols))),
        shape=(len(nodes), len(nodes)),
    ).tocsr()
    node_of_point = np.full(len(xyz), -1, dtype=np.int64)
    node_of_point[above] = node_of
    stem_of_node = np.full(len(nodes), -1, dtype=np.int64)
    start_of_node = np.zeros(len(nodes))
    for k in range(len(seeds) - 1, -1, -1):
        mine = node_of_point[seeds[k]]
        stem_of_node[mine] = k
        start_of_node[mine] = np.inf
        np.minimum.at(start_of_node, mine, start[k] if start is not None else 0.0)
    # Every stem is one more node, linked to its seed nodes at their start cost (a
    # sparse graph has no links of cost 0).
    n = len(nodes)
    sources = np.flatnonzero(stem_of_node >= 0)
    graph = graph.tocoo()
    graph = coo_matrix(
        (
            np.r_[graph.data, start_of_node[sources] + 1e-9],
            (np.r_[graph.row, n + stem_of_node[sources]], np.r_[graph.col, sources]),
        ),
        shape=(n + len(seeds),) * 2,
    ).tocsr()
    _, _, nearest = dijkstra(
        graph,
        directed=False,
        indices=np.arange(n, n + len(seeds)),
        min_only=True,
        return_predecessors=True,
    )
    stem = np.where(nearest[:n] >= 0, nearest[:n] - n, -1)
    owner[above] = stem[node_of]
    return owner


def _links(
    nodes: np.ndarray, crown: np.ndarray, link: float, shorter: float, *, first: bool
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Links between nodes longer than ``shorter`` and up to ``link`` (m).

    The first kind joins every node; a gap link joins crown nodes only, one per voxel
    of a third of its length (a few links per node whatever the length). Each link's
    length is returned with its horizontal part weighted by ``ACROSS_COST``.
    """
    from scipy.spatial import cKDTree

    if first:
        sub = np.arange(len(nodes))
    else:
        sub = voxel_representatives(nodes, link / 3)[0]
        sub = sub[crown[sub]]
    pairs = cKDTree(nodes[sub]).query_pairs(link, output_type="ndarray")
    d = nodes[sub[pairs[:, 0]]] - nodes[sub[pairs[:, 1]]]
    keep = np.linalg.norm(d, axis=1) > shorter
    length = np.hypot(d[keep, 2], ACROSS_COST * np.hypot(d[keep, 0], d[keep, 1]))
    return sub[pairs[keep, 0]], sub[pairs[keep, 1]], length


def tree_top(tree: np.ndarray) -> np.ndarray:
    """(3,) a tree's highest point that is no stray (has a neighbour).

    One other point within 30 cm is enough: the tree's points were reached by a
    path from its stem, which no point far from the crown is, and the tip of a
    sparse crown is often two beam hits on one twig. NaN for no points.
    """
    from amrst.measure.dbh import with_company

    if not len(tree):
        return np.full(3, np.nan)
    order = np.argsort(-tree[:, 2])
    for start in range(0, len(order), 200):
        kept = with_company(
            tree, np.ones(len(tree), np.int64), order[start : start + 200], others=1
        )
        if len(kept):
            return np.asarray(tree[kept[np.argmax(tree[kept, 2])]], dtype=float)
    return np.asarray(tree[order[0]], dtype=float)
