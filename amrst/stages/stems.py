"""Stems above the ground, and which stem each point belongs to (for ``scene.py``).

:func:`find_stems` clusters a slice above the ground and keeps the clusters that cross
it and are narrow enough to be stems (a circle fit gives centre and radius);
:func:`assign_to_stems` gives every point above the ground to the stem it reaches by
the shortest path through neighbouring points.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from amrst.geometry import kasa_circle

if TYPE_CHECKING:
    from amrst.stages.scene import SceneParams


@dataclass(frozen=True, slots=True)
class Stem:
    """One stem found in the slice above the ground."""

    xy: np.ndarray  # (2,) centre of the fitted circle (local frame)
    radius_m: float  # nan when the circle fit was not usable
    n_points: int


def _components(pts: np.ndarray, link: float) -> tuple[int, np.ndarray]:
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    pairs = _pairs_within(pts, link)
    g = coo_matrix(
        (np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])), shape=(len(pts), len(pts))
    )
    n, lab = connected_components(g, directed=False)
    return int(n), lab


def crosses_slice(h: np.ndarray, params: SceneParams) -> bool:
    """Tell whether heights ``h`` span the stem slice, as a stem crossing it does.

    They must reach into its lowest quarter and its highest.
    """
    quarter = 0.25 * (params.stem_high_m - params.stem_low_m)
    return not (
        h.min() > params.stem_low_m + quarter or h.max() < params.stem_high_m - quarter
    )


def find_stems(
    xyz: np.ndarray, h: np.ndarray, above: np.ndarray, params: SceneParams
) -> tuple[list[Stem], np.ndarray, np.ndarray]:
    """Stems in the slice; also each slice point's stem number (-1 none) and index."""
    hs = h[above]
    sl = above[(hs >= params.stem_low_m) & (hs <= params.stem_high_m)]
    if len(sl) < 10:
        return [], np.zeros(0, dtype=np.int64), sl
    n, lab = _components(xyz[sl], params.link_m)
    stems: list[Stem] = []
    out = np.full(len(sl), -1, dtype=np.int64)
    for k in range(n):
        m = lab == k
        if m.sum() < 10 or not crosses_slice(h[sl[m]], params):
            continue
        pts = xyz[sl[m], :2]
        if np.ptp(pts, axis=0).max() > params.stem_max_width_m:
            continue
        out[m] = len(stems)
        stems.append(_circle(pts))
    return stems, out, sl


def _circle(pts: np.ndarray) -> Stem:
    """Kasa circle fit of a stem slice; the median when the fit is unusable."""
    med = np.median(pts, axis=0)
    centre, r2 = kasa_circle(pts, med)
    spread = float(np.max(np.hypot(*(pts - med).T)))
    if not r2 > 0 or np.sqrt(r2) > max(1.5 * spread, 0.05):
        return Stem(med, float("nan"), len(pts))
    return Stem(centre, float(np.sqrt(r2)), len(pts))


def assign_to_stems(
    xyz: np.ndarray,
    h: np.ndarray,
    above: np.ndarray,
    seeds: list[np.ndarray],
    params: SceneParams,
) -> np.ndarray:
    """Stem number of each point above the ground (0 = the tree), -1 for shrubs."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import dijkstra

    from amrst.neighbours import NearestTree
    from amrst.stages.voxels import voxel_representatives

    # Paths are traced on one point per voxel (a third of the link): ten times fewer
    # links than on the 3 cm working points, same labels at this scale.
    above_xyz = xyz[above]
    reps, owner_of = voxel_representatives(above_xyz, params.link_m / 3)
    pts = above_xyz[reps]
    pairs = _pairs_within(pts, params.link_m)
    d = _pair_lengths(pts, pairs)
    graph = coo_matrix(
        (d, (pairs[:, 0], pairs[:, 1])), shape=(len(pts), len(pts))
    ).tocsr()
    pos = np.full(len(xyz), -1, dtype=np.int64)
    pos[above] = owner_of  # working point -> its voxel's node
    node_stem = np.full(len(pts), -1, dtype=np.int64)
    for k in range(len(seeds) - 1, -1, -1):  # the tree of interest wins a shared voxel
        node_stem[pos[seeds[k]]] = k
    nodes = np.flatnonzero(node_stem >= 0)
    _, _, sources = dijkstra(
        graph, directed=False, indices=nodes, min_only=True, return_predecessors=True
    )
    owner = np.where(sources >= 0, node_stem[np.maximum(sources, 0)], -1)
    h_nodes = h[above[reps]]
    # Pieces that reach no stem: crown parts (high) go with their nearest labelled
    # point, shrubs (low) stay "other".
    lost = np.flatnonzero(owner < 0)
    reached = np.flatnonzero(owner >= 0)
    if len(lost) and len(reached):
        high = lost[h_nodes[lost] > params.crown_height_m]
        # One thread, as for the skeleton's islands (a few thousand points).
        nn = NearestTree(pts[reached], threads=1).query(pts[high])[1]
        owner[high] = owner[reached[nn]]
    return np.asarray(owner[owner_of])


def _pairs_within(pts: np.ndarray, link: float) -> np.ndarray:
    """(P, 2) pairs i < j of points within ``link`` of each other, in no set order.

    A sliding-midpoint tree without node compaction builds faster than scipy's
    default (median splits) and finds the same pairs; every caller makes a canonical CSR matrix or
    components of them, which do not depend on the order.
    """
    from scipy.spatial import cKDTree

    tree = cKDTree(pts, balanced_tree=False, compact_nodes=False)
    return np.asarray(tree.query_pairs(link, output_type="ndarray"))


def _pair_lengths(pts: np.ndarray, pairs: np.ndarray) -> np.ndarray:
    """Length of each (i, j) pair: ``np.linalg.norm(pts[i] - pts[j], axis=1)``.

    Coordinate by coordinate on contiguous columns (faster than the 2-D norm);
    the same sums in the same order, so the same bits.
    """
    i, j = np.ascontiguousarray(pairs[:, 0]), np.ascontiguousarray(pairs[:, 1])
    sq = np.zeros(len(pairs))
    for d in range(3):
        col = np.ascontiguousarray(pts[:, d])
        diff = col[i] - col[j]
        diff *= diff
        sq += diff
    return np.sqrt(sq, out=sq)
