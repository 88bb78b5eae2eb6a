"""How far each registered scan of a plot lies from the others: its residual.

A scan's residual is the RMS distance from a sample of its points to the surfaces of
the other placed scans where they overlap, measured along each surface's normal. Point
to surface, not point to point: the distance from a point to its nearest neighbour in
another scan is mostly the spacing of that scan's points (a few centimetres at a plot's
far side, whatever the pose), while the distance to the surface is what the pose moves.
Only points whose nearest neighbours lie on a surface (ground, bark) count; leaves and
twigs, which wind and sampling scatter, do not.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from amrst.neighbours import THREADS, NearestTree

if TYPE_CHECKING:
    from collections.abc import Sequence

    from amrst.types import Transform

#: Points of each scan whose distance is measured (a seeded sample).
RESIDUAL_POINTS = 20_000
#: Points of each scan that make its surfaces (an even stride beyond).
SURFACE_TREE_POINTS = 1_000_000
#: A point counts when another scan has a point this near it (m).
RESIDUAL_REACH_M = 0.2
#: Neighbours that make the surface around the nearest point.
SURFACE_POINTS = 12
#: They make a surface when their smallest spread is under this share of the three.
FLAT_SHARE = 0.02
SEED = 0


def scan_residuals(
    points: Sequence[np.ndarray],
    poses: Sequence[Transform | None],
    *,
    threads: int = THREADS,
) -> tuple[float, ...]:
    """Return each scan's residual against the other placed scans (m).

    Parameters
    ----------
    points : sequence of (N_k, 3) float64
        Each scan's points in its local frame.
    poses : sequence of (4, 4) float64 or None
        Scan k's local frame -> the reference's local frame (None: not placed).
    threads : int

    Returns
    -------
    tuple of float
        NaN for a scan not placed, or with no surface of another scan in reach.
    """
    placed = [k for k, pose in enumerate(poses) if pose is not None]
    moved = {k: _moved(points[k], poses[k]) for k in placed}
    stride = {k: max(1, -(-len(moved[k]) // SURFACE_TREE_POINTS)) for k in placed}
    trees = {k: NearestTree(moved[k][:: stride[k]], threads) for k in placed}
    out = []
    for k, pose in enumerate(poses):
        others = [j for j in placed if j != k]
        if pose is None or not others or not len(moved[k]):
            out.append(float("nan"))
            continue
        out.append(_residual(_sample(moved[k]), [trees[j] for j in others]))
    return tuple(out)


def bundle_error(residuals: Sequence[float]) -> float:
    """Return the RMS of the scans' residuals (NaN when none is known)."""
    known = np.asarray([r for r in residuals if np.isfinite(r)], dtype=float)
    return float(np.sqrt(np.mean(known**2))) if len(known) else float("nan")


def _moved(xyz: np.ndarray, pose: Transform | None) -> np.ndarray:
    assert pose is not None
    return np.asarray(np.asarray(xyz, dtype=float) @ pose[:3, :3].T + pose[:3, 3])


def _sample(xyz: np.ndarray) -> np.ndarray:
    if len(xyz) <= RESIDUAL_POINTS:
        return xyz
    rng = np.random.default_rng(SEED)
    return xyz[np.sort(rng.choice(len(xyz), RESIDUAL_POINTS, replace=False))]


def _residual(query: np.ndarray, others: Sequence[NearestTree]) -> float:
    """RMS distance of ``query`` to the surfaces of the nearest of ``others``."""
    found = [tree.query(query, 1, RESIDUAL_REACH_M) for tree in others]
    dist = np.column_stack([d for d, _ in found])
    nearest = np.argmin(dist, axis=1)
    near = np.isfinite(dist[np.arange(len(query)), nearest])
    squares = []
    for m, tree in enumerate(others):
        rows = np.flatnonzero(near & (nearest == m))
        if not len(rows) or tree.n < SURFACE_POINTS:
            continue
        anchor = tree.points[found[m][1][rows]]
        _, around = tree.query(anchor, SURFACE_POINTS)
        squares.append(_to_surface(query[rows], tree.points[around]) ** 2)
    every = np.concatenate(squares) if squares else np.zeros(0)
    return float(np.sqrt(every.mean())) if len(every) else float("nan")


def _to_surface(query: np.ndarray, around: np.ndarray) -> np.ndarray:
    """Distances of ``query`` (M, 3) along the normals of ``around`` (M, K, 3), flat ones."""
    centre = around.mean(axis=1)
    spread = around - centre[:, None, :]
    cov = np.einsum("mki,mkj->mij", spread, spread)
    values, vectors = np.linalg.eigh(cov)  # ascending: the normal is the first
    flat = values[:, 0] < FLAT_SHARE * np.maximum(values.sum(axis=1), 1e-12)
    normal = vectors[:, :, 0]
    return np.asarray(np.abs(np.einsum("mi,mi->m", query - centre, normal))[flat])
