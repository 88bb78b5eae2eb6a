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
from amrst.sampling import random_rows

if TYPE_CHECKING:
    from collections.abc import Sequence

    from amrst.types import Transform

#: Points of each scan whose distance is measured (a seeded sample).
RESIDUAL_POINTS = 10_000
#: Points of each scan that make its surfaces (an even stride beyond).
SURFACE_TREE_POINTS = 1_000_000
#: A point counts when another scan has a point this near it (m).
RESIDUAL_REACH_M = 0.2
#: Neighbours that make the surface around the nearest point.
SURFACE_POINTS = 12
#: They make a surface when their smallest spread is under this share of the three.
FLAT_SHARE = 0.02
SEED = 0


class Surfaces:
    """The scans of a plot as surfaces to measure distances to.

    One KD-tree per scan, in the scan's own frame, built once for every residual.

    Parameters
    ----------
    points : sequence of (N_k, 3) float64
        Each scan's points in its local frame.
    threads : int
    """

    def __init__(self, points: Sequence[np.ndarray], threads: int = THREADS) -> None:
        self.points = [np.asarray(p, dtype=float) for p in points]
        self.trees = [
            NearestTree(p[:: max(1, -(-len(p) // SURFACE_TREE_POINTS))], threads)
            for p in self.points
        ]

    def residual(self, k: int, onto: dict[int, Transform]) -> float:
        """Return scan k's RMS distance to the surfaces of the scans ``onto`` names.

        ``onto[j]`` maps scan k's frame into scan j's. NaN when no surface is in reach.
        """
        query = random_rows(self.points[k], RESIDUAL_POINTS, SEED, in_order=True)
        if not len(query) or not onto:
            return float("nan")
        moved = [query @ T[:3, :3].T + T[:3, 3] for T in onto.values()]
        return _residual(moved, [self.trees[j] for j in onto])


def scan_residuals(
    surfaces: Surfaces, poses: Sequence[Transform | None]
) -> tuple[float, ...]:
    """Return each scan's residual against the other placed scans (m).

    Parameters
    ----------
    surfaces : Surfaces
        The plot's scans.
    poses : sequence of (4, 4) float64 or None
        Scan k's local frame -> the reference's local frame (None: not placed).

    Returns
    -------
    tuple of float
        NaN for a scan not placed, or with no surface of another scan in reach.
    """
    from amrst.types import invert_transform

    out = []
    for k, pose in enumerate(poses):
        onto = {
            j: invert_transform(other) @ pose
            for j, other in enumerate(poses)
            if j != k and other is not None and pose is not None
        }
        out.append(surfaces.residual(k, onto) if pose is not None else float("nan"))
    return tuple(out)


def bundle_error(residuals: Sequence[float]) -> float:
    """Return the RMS of the scans' residuals (NaN when none is known)."""
    known = np.asarray([r for r in residuals if np.isfinite(r)], dtype=float)
    return float(np.sqrt(np.mean(known**2))) if len(known) else float("nan")


def _residual(queries: Sequence[np.ndarray], others: Sequence[NearestTree]) -> float:
    """RMS distance to the surfaces of the nearest of ``others``.

    ``queries[m]`` are the same points in the frame of ``others[m]``.
    """
    found = [
        tree.query(q, 1, RESIDUAL_REACH_M)
        for q, tree in zip(queries, others, strict=True)
    ]
    dist = np.column_stack([d for d, _ in found])
    nearest = np.argmin(dist, axis=1)
    near = np.isfinite(dist[np.arange(len(dist)), nearest])
    squares = []
    for m, tree in enumerate(others):
        rows = np.flatnonzero(near & (nearest == m))
        if not len(rows) or tree.n < SURFACE_POINTS:
            continue
        anchor = tree.points[found[m][1][rows]]
        _, around = tree.query(anchor, SURFACE_POINTS)
        squares.append(_to_surface(queries[m][rows], tree.points[around]) ** 2)
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
