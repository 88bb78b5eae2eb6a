"""How firmly a registration holds each of its six degrees of freedom.

The final alignment's point-to-plane normal equations tell how much the residuals grow
when the pose moves along one axis while the other five re-adjust (the Schur
complement of that axis). That growth, per unit of motion, is the axis's strength: 1
when every overlap point's surface faces along the axis, 0 when the surfaces slide
freely (a bare stem turning about its own axis, a flat ground shifting sideways). Seen
as in Leica Cyclone's "strength" per axis. No Qt, no pyvista.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    from amrst.types import Transform

AXES = ("tx", "ty", "tz", "rx", "ry", "rz")
#: Below this an axis is called weak: the residuals grow by less than 5 % of the
#: motion (translation) or of the motion times the overlap's radius (rotation).
WEAK_STRENGTH = 0.05
_NORMAL_NEIGHBOURS = 12
_MAX_POINTS = 20_000


@dataclass(frozen=True, slots=True)
class Strength:
    """The strength of each axis of a pose, in [0, 1].

    Attributes
    ----------
    values : dict[str, float]
        ``tx``, ``ty``, ``tz`` (translations along the target frame's axes) and ``rx``,
        ``ry``, ``rz`` (rotations about them through the overlap's centre); NaN when
        the overlap has too few points to tell.
    n_points : int
        Overlap points the normal equations were built on.
    """

    values: dict[str, float]
    n_points: int

    @property
    def weak(self) -> tuple[str, ...]:
        """Axes weaker than :data:`WEAK_STRENGTH`, weakest first."""
        held = [(v, k) for k, v in self.values.items() if np.isfinite(v)]
        return tuple(k for v, k in sorted(held) if v < WEAK_STRENGTH)

    def advice(self) -> str:
        """One sentence on the weak axes for the verdict, or "" when all are held."""
        weak = self.weak
        if not weak:
            return ""
        words = {
            "tx": "shift along x",
            "ty": "shift along y",
            "tz": "height",
            "rx": "tilt about x",
            "ry": "tilt about y",
            "rz": "rotation about the stem (vertical)",
        }
        named = ", ".join(words[k] for k in weak)
        return f"Poorly held: {named}; check the stem slices before accepting."


def _normals(at: np.ndarray, cloud: np.ndarray, tree: object) -> np.ndarray:
    """Estimate unit normals of ``cloud`` at ``at`` from their neighbours' PCA."""
    idx = tree.query(at, k=_NORMAL_NEIGHBOURS)[1]  # type: ignore[attr-defined]
    nb = cloud[idx] - cloud[idx].mean(axis=1, keepdims=True)
    cov = np.einsum("nki,nkj->nij", nb, nb)
    return np.asarray(np.linalg.eigh(cov)[1][:, :, 0])


def axis_strength(
    target_xyz: np.ndarray,
    source_xyz: np.ndarray,
    T_target_source: Transform,
    max_dist_m: float,
    seed: int = 0,
) -> Strength:
    """Measure the strength of each axis of ``T_target_source``.

    Parameters
    ----------
    target_xyz, source_xyz : (N, 3), (M, 3) float64
        The scans in their own frames (the points the pose was fitted on).
    T_target_source : (4, 4) float64
    max_dist_m : float
        Source points farther than this from the target after the move are not
        overlap and do not count.
    seed : int
        Seed of the sample drawn from large overlaps.

    Returns
    -------
    Strength
    """
    from scipy.spatial import cKDTree

    nan = dict.fromkeys(AXES, float("nan"))
    if len(target_xyz) < _NORMAL_NEIGHBOURS or len(source_xyz) == 0:
        return Strength(nan, 0)
    T = np.asarray(T_target_source, float)
    moved = np.asarray(source_xyz, float) @ T[:3, :3].T + T[:3, 3]
    if len(moved) > _MAX_POINTS:
        rng = np.random.default_rng(seed)
        moved = moved[rng.choice(len(moved), _MAX_POINTS, replace=False)]
    target = np.asarray(target_xyz, float)
    tree = cKDTree(target)
    d, nearest = tree.query(moved, distance_upper_bound=max_dist_m)
    inside = np.isfinite(d)
    if inside.sum() < _NORMAL_NEIGHBOURS:
        return Strength(nan, int(inside.sum()))
    p = moved[inside]
    n = _normals(target[nearest[inside]], target, tree)
    r = p - p.mean(axis=0)
    radius = float(np.sqrt(np.mean(np.sum(r**2, axis=1))))
    if radius <= 0:
        return Strength(nan, len(p))
    # One row per point: the normal displacement per unit motion along each axis,
    # rotations taken per radian times the overlap's RMS radius (dimensionless).
    J = np.hstack([n, np.cross(r, n) / radius])
    H = J.T @ J / len(p)
    ridge = 1e-12 * max(float(np.trace(H)), 1e-300)
    cov = np.linalg.inv(H + ridge * np.eye(6))
    held = 1.0 / np.diag(cov)
    values = {k: float(np.sqrt(max(v, 0.0))) for k, v in zip(AXES, held, strict=True)}
    return Strength(values, len(p))
