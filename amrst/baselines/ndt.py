"""Normal Distributions Transform, point-to-distribution (Biber 2003, Magnusson 2009).

The target is cut into cubic cells; each cell with enough points becomes a Gaussian
(mean, regularised covariance). A source point moved by the pose scores the
Gaussian likelihoods of the cells whose means are near it (a KD-tree on the means
finds them), with Magnusson's mixture constants ``d1, d2`` for outliers. The pose is a
rotation vector about the source centroid plus a translation; each iteration takes a
Newton step with the analytic gradient and Hessian of the score, made positive
definite if needed, clamped, and checked by a backtracking line search. Cells go
from coarse to fine (2, 1, 0.5 m by default), and a time budget bounds the run.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from typing import TYPE_CHECKING, cast

import numpy as np

from amrst.baselines._common import (
    MethodResult,
    Stopwatch,
    finish,
    local_pair,
    to_local,
    voxel_down,
)
from amrst.geometry import rotvec_matrix
from amrst.types import Cloud, Transform, make_transform

if TYPE_CHECKING:
    import numpy.typing as npt


@dataclass(frozen=True, slots=True, kw_only=True)
class NdtParams:
    """NDT settings.

    cell_sizes_m : cell edge of each coarse-to-fine level (m).
    max_iterations : Newton iterations per level.
    min_points_per_cell : cells with fewer target points are ignored.
    outlier_ratio : Magnusson's share of outliers in the score mixture (PCL uses 0.55).
    neighbours : cell means scored per source point (the nearest ones within one cell).
    source_voxel_m, max_source_points : source downsampling (voxel, then seeded sample).
    max_step_rot_deg : largest rotation of one step (deg); translation is capped at half
        a cell.
    tol_translation_m, tol_rotation_deg : a step smaller than both ends the level.
    max_seconds : time budget of the whole run (s).
    """

    cell_sizes_m: tuple[float, ...] = (2.0, 1.0, 0.5)
    max_iterations: int = 30
    min_points_per_cell: int = 5
    outlier_ratio: float = 0.55
    neighbours: int = 4
    source_voxel_m: float = 0.1
    max_source_points: int = 8000
    max_step_rot_deg: float = 5.0
    tol_translation_m: float = 1e-4
    tol_rotation_deg: float = 1e-3
    max_seconds: float = 20.0
    seed: int = 0

    def __post_init__(self) -> None:
        if not self.cell_sizes_m or min(self.cell_sizes_m) <= 0:
            raise ValueError("cell_sizes_m must be positive")
        if not 0.0 <= self.outlier_ratio < 1.0:
            raise ValueError("outlier_ratio must be in [0, 1)")


@dataclass(frozen=True, slots=True)
class NdtGrid:
    """The target's cell Gaussians at one cell size."""

    cell_m: float
    means: np.ndarray  # (C, 3)
    inv_covs: np.ndarray  # (C, 3, 3)
    d1: float
    d2: float


def build_grid(
    xyz: np.ndarray, cell_m: float, min_points: int, outlier_ratio: float
) -> NdtGrid:
    """Cell Gaussians of a target cloud, eigenvalues floored at 1 % of the largest.

    Parameters
    ----------
    xyz : (N, 3) float64
    cell_m : float
        Cell edge (m).
    min_points : int
    outlier_ratio : float

    Returns
    -------
    NdtGrid
    """
    keys = np.floor(xyz / cell_m).astype(np.int64)
    _, inv, counts = np.unique(keys, axis=0, return_inverse=True, return_counts=True)
    inv = inv.reshape(-1)
    # np.bincount with weights gives float64 (numpy's stubs say intp).
    means = cast(
        "npt.NDArray[np.float64]",
        np.stack([np.bincount(inv, weights=xyz[:, k]) for k in range(3)], axis=1),
    )
    means /= counts[:, None]
    dev = xyz - means[inv]
    cov = np.empty((len(counts), 3, 3))
    for i in range(3):
        for j in range(i, 3):
            cov[:, i, j] = cov[:, j, i] = np.bincount(
                inv, weights=dev[:, i] * dev[:, j]
            )
    ok = counts >= max(min_points, 3)
    means, cov = means[ok], cov[ok] / (counts[ok] - 1)[:, None, None]
    w, V = np.linalg.eigh(cov)
    w = np.maximum(w, np.maximum(0.01 * w[:, 2:3], 1e-8))
    inv_covs = np.einsum("nij,nj,nkj->nik", V, 1.0 / w, V)
    # Magnusson (2009) eq. 6.8: a Gaussian plus a uniform outlier floor, as d1, d2.
    c1 = 10.0 * (1.0 - outlier_ratio)
    c2 = max(outlier_ratio, 1e-9) / cell_m**3
    d3 = -np.log(c2)
    d1 = -np.log(c1 + c2) - d3
    d2 = -2.0 * np.log((-np.log(c1 * np.exp(-0.5) + c2) - d3) / d1)
    return NdtGrid(cell_m, means, inv_covs, float(d1), float(d2))


class _Scorer:
    """Score, gradient and Hessian of moved source points against one NdtGrid."""

    def __init__(self, grid: NdtGrid, neighbours: int) -> None:
        from scipy.spatial import cKDTree

        self.grid = grid
        self.k = min(neighbours, len(grid.means))
        self.tree = cKDTree(grid.means)

    def _pairs(self, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        d, j = self.tree.query(y, k=self.k, distance_upper_bound=self.grid.cell_m)
        d, j = d.reshape(len(y), -1), j.reshape(len(y), -1)
        pi, col = np.nonzero(np.isfinite(d))
        return pi, j[pi, col]

    def score(self, y: np.ndarray) -> float:
        """Minus the summed likelihood (lower is better) of points ``y`` (M, 3)."""
        pi, vi = self._pairs(y)
        x = y[pi] - self.grid.means[vi]
        q = np.einsum("ni,nij,nj->n", x, self.grid.inv_covs[vi], x)
        return float(-np.exp(-0.5 * self.grid.d2 * q).sum())

    def derivatives(
        self, y: np.ndarray, c: np.ndarray
    ) -> tuple[float, np.ndarray, np.ndarray]:
        """Score, gradient (6,) and Hessian (6, 6) for a rotation about ``c`` (3,)."""
        pi, vi = self._pairs(y)
        if len(pi) == 0:
            return 0.0, np.zeros(6), np.zeros((6, 6))
        d2 = self.grid.d2
        S = self.grid.inv_covs[vi]
        x = y[pi] - self.grid.means[vi]
        z = y[pi] - c
        a = np.einsum("nij,nj->ni", S, x)
        e = np.exp(-0.5 * d2 * np.einsum("ni,ni->n", x, a))
        # Jacobian of the moved point: d/d(omega) = -[z]x, d/dt = I.
        n = len(z)
        J = np.zeros((n, 3, 6))
        J[:, 0, 1], J[:, 0, 2] = z[:, 2], -z[:, 1]
        J[:, 1, 0], J[:, 1, 2] = -z[:, 2], z[:, 0]
        J[:, 2, 0], J[:, 2, 1] = z[:, 1], -z[:, 0]
        J[:, 0, 3] = J[:, 1, 4] = J[:, 2, 5] = 1.0
        aJ = np.einsum("ni,nij->nj", a, J)
        w = d2 * e
        grad = aJ.T @ w
        JSJ = np.einsum("nki,nkj->nij", J, np.einsum("nkl,nlj->nkj", S, J))
        H = np.einsum("n,nij->ij", w, JSJ) - d2 * (aJ * w[:, None]).T @ aJ
        # Second derivative of R(omega) z at 0 is (e_i z_j + e_j z_i) / 2 - delta_ij z.
        az = np.einsum("n,ni,nj->ij", w, a, z)
        H[:3, :3] += 0.5 * (az + az.T) - np.eye(3) * np.einsum("n,ni,ni->", w, a, z)
        return float(-e.sum()), grad, H


def _newton_step(grad: np.ndarray, H: np.ndarray) -> np.ndarray:
    w, V = np.linalg.eigh(0.5 * (H + H.T))
    floor = max(1e-6 * max(abs(w).max(), 1e-12), 1e-12)
    # Where the score is not convex, flip and floor the curvature (damped Newton).
    w = np.maximum(np.abs(w), floor)
    return cast("np.ndarray", -(V @ ((V.T @ grad) / w)))


def ndt_align(
    target_xyz: np.ndarray,
    source_xyz: np.ndarray,
    T_init: Transform,
    params: NdtParams,
    clock: Stopwatch,
) -> tuple[Transform, int, bool]:
    """Align ``source_xyz`` to the NDT of ``target_xyz`` from ``T_init``.

    Parameters
    ----------
    target_xyz, source_xyz : (N, 3), (M, 3) float64
    T_init : (4, 4) float64
    params : NdtParams
    clock : Stopwatch
        Receives the stages ``grid`` and ``newton``.

    Returns
    -------
    T_local : (4, 4) float64
    iterations : int
        Newton iterations over all levels.
    converged : bool
        Whether the finest level met the step tolerance within its limits.
    """
    deadline = time.perf_counter() + params.max_seconds
    src = voxel_down(source_xyz, params.source_voxel_m)
    if len(src) > params.max_source_points:
        rng = np.random.default_rng(params.seed)
        src = src[rng.choice(len(src), params.max_source_points, replace=False)]
    R, t = T_init[:3, :3].copy(), T_init[:3, 3].copy()
    iterations, converged = 0, False
    max_rot = np.radians(params.max_step_rot_deg)
    tol_rot = np.radians(params.tol_rotation_deg)
    for cell in params.cell_sizes_m:
        with clock.stage("grid"):
            grid = build_grid(
                target_xyz, cell, params.min_points_per_cell, params.outlier_ratio
            )
            if len(grid.means) == 0:
                continue
            scorer = _Scorer(grid, params.neighbours)
        converged = False
        with clock.stage("newton"):
            for _ in range(params.max_iterations):
                if time.perf_counter() > deadline:
                    return make_transform(R, t), iterations, False
                iterations += 1
                y = src @ R.T + t
                c = y.mean(axis=0)
                f0, grad, H = scorer.derivatives(y, c)
                step = _newton_step(grad, H)
                # Clamp the step, then halve it until the score improves.
                scale = min(1.0, max_rot / max(np.linalg.norm(step[:3]), 1e-12))
                norm = cast("float", np.linalg.norm(step[3:]))
                scale = min(scale, 0.5 * cell / max(norm, 1e-12))
                step *= scale
                accepted = False
                for _ in range(8):
                    dR = rotvec_matrix(step[:3])
                    y_new = (y - c) @ dR.T + c + step[3:]
                    if scorer.score(y_new) < f0:
                        accepted = True
                        break
                    step *= 0.5
                if not accepted:
                    converged = True
                    break
                R, t = dR @ R, dR @ (t - c) + c + step[3:]
                if (
                    np.linalg.norm(step[:3]) < tol_rot
                    and np.linalg.norm(step[3:]) < params.tol_translation_m
                ):
                    converged = True
                    break
    return make_transform(R, t), iterations, converged


def register_ndt(
    target: Cloud,
    source: Cloud,
    params: NdtParams = NdtParams(),
    T_init: Transform | None = None,
) -> MethodResult:
    """NDT registration from the identity (the paper's NDT baseline) or ``T_init``.

    Parameters
    ----------
    target, source : Cloud
    params : NdtParams
    T_init : (4, 4) float64 or None
        Start ``T_target_source`` in world coordinates; None is the identity.

    Returns
    -------
    MethodResult
    """
    clock = Stopwatch()
    tgt, src, origin = local_pair(target, source)
    start = (
        np.eye(4)
        if T_init is None
        else to_local(np.asarray(T_init, dtype=float), origin)
    )
    T, iterations, converged = ndt_align(tgt, src, start, params, clock)
    return finish(
        tgt, src, T, origin, clock, iterations=iterations, converged=converged
    )
