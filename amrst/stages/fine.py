"""Fine registration: LM-ICP (the paper's) and a robust point-to-plane alternative.

``lm_icp`` is the paper's section II.E: point-to-point residuals r_i = R p_i + t - q_π(i)
on the leaf points, Levenberg-Marquardt steps (JᵀJ + λ D) Δx = -Jᵀe with D = diag(JᵀJ),
correspondences re-found each iteration within a maximum distance. It is the default,
on the leaf points, because trunks seen from two sides pull a fit on wood (or on
everything) into a biased pose, as the paper observes. ``robust_plane`` (point-to-plane
ICP with a Tukey kernel, Open3D) is the alternative for scans with little foliage.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np

from amrst.geometry import rotvec_matrix
from amrst.neighbours import THREADS
from amrst.progress import NULL_REPORTER, Reporter
from amrst.stages.nearest_cache import NearestCache
from amrst.types import Transform, make_transform

if TYPE_CHECKING:
    from amrst.neighbours import NearestTree

FINE_METHODS = ("robust_plane", "lm_icp", "none")
POINT_SETS = ("all", "leaf", "wood")
# Fewer sampled points than this make the fit a lottery (LM-ICP needs 6 at least).
MIN_FIT_POINTS = 100


@dataclass(frozen=True, slots=True, kw_only=True)
class FineParams:
    """Fine registration settings."""

    method: str = field(
        default="lm_icp",
        metadata={
            "choices": FINE_METHODS,
            "help": "robust_plane: point-to-plane ICP with a Tukey kernel; lm_icp: the paper's Levenberg-Marquardt point-to-point ICP; none: keep the coarse result.",
        },
    )
    points: str = field(
        default="leaf",
        metadata={
            "choices": POINT_SETS,
            "help": "Which points drive the fit: all, leaf (the paper's choice) or wood.",
        },
    )
    voxel_size_m: float = field(
        default=0.03,
        metadata={
            "unit": "m",
            "min": 0.0,
            "max": 0.5,
            "help": "Thin both clouds to this voxel size for the fit (0 = all points).",
        },
    )
    max_points: int = field(
        default=5000,
        metadata={
            "unit": "points",
            "min": 0,
            "max": 10_000_000,
            "help": "After thinning, at most this many source points (a seeded sample) drive the fit; the target keeps all, and fitness and inlier RMSE are measured on all thinned points. Time grows with it, accuracy hardly beyond a few thousand (0 = all; otherwise at least 100).",
        },
    )
    max_corr_dist_m: float = field(
        default=0.15,
        metadata={
            "unit": "m",
            "min": 0.005,
            "max": 5.0,
            "help": "Correspondence distance of the first scale. Typical 2-5 × the expected coarse error.",
        },
    )
    min_corr_dist_m: float = field(
        default=0.02,
        metadata={
            "unit": "m",
            "min": 0.001,
            "max": 5.0,
            "help": "Correspondence distance of the last scale; the scales step geometrically from max_corr_dist_m down to this. A tight last scale locks onto surfaces both scans saw. Typical 0.01-0.05.",
        },
    )
    scales: int = field(
        default=3,
        metadata={
            "unit": "",
            "min": 1,
            "max": 6,
            "help": "Coarse-to-fine steps of the correspondence distance.",
        },
    )
    max_iterations: int = field(
        default=30,
        metadata={
            "unit": "iterations",
            "min": 1,
            "max": 500,
            "help": "Iterations per scale.",
        },
    )
    tolerance: float = field(
        default=1e-5,
        metadata={
            "unit": "relative",
            "min": 0.0,
            "max": 0.1,
            "help": "Stop when the cost changes less than this share.",
        },
    )

    def __post_init__(self) -> None:
        if self.method not in FINE_METHODS:
            raise ValueError(f"fine method must be one of {FINE_METHODS}")
        if self.points not in POINT_SETS:
            raise ValueError(f"fine points must be one of {POINT_SETS}")
        if self.min_corr_dist_m > self.max_corr_dist_m:
            raise ValueError(
                f"fine.min_corr_dist_m ({self.min_corr_dist_m} m) must be at most "
                f"fine.max_corr_dist_m ({self.max_corr_dist_m} m); lower one or raise the other"
            )
        if self.max_points != 0 and self.max_points < MIN_FIT_POINTS:
            raise ValueError(
                f"fine max_points must be 0 (all points) or at least {MIN_FIT_POINTS}, "
                f"not {self.max_points}"
            )


@dataclass(frozen=True, slots=True)
class FineResult:
    """Refined transform and how well it fits."""

    T_target_source: Transform
    method: str
    converged: bool
    iterations: int
    fitness: (
        float  # inlier fraction of the source points (within the last max distance)
    )
    inlier_rmse_m: float
    max_corr_dist_m: float  # the last scale's distance


def _ladder(params: FineParams) -> np.ndarray:
    """Correspondence distances, geometric from max_corr_dist_m to min_corr_dist_m."""
    if params.scales == 1:
        return np.array([params.max_corr_dist_m])
    lo = min(params.min_corr_dist_m, params.max_corr_dist_m)
    return np.geomspace(params.max_corr_dist_m, lo, params.scales)


def lm_icp(
    src: np.ndarray,
    tgt: np.ndarray,
    T_init: Transform,
    max_dist: float,
    iters: int,
    tol: float,
    *,
    reporter: Reporter = NULL_REPORTER,
    tree: NearestTree | None = None,
    nearest: NearestCache | None = None,
) -> tuple[Transform, int, bool]:
    """Levenberg-Marquardt point-to-point ICP. Returns (T, iterations, converged).

    ``tree`` is a :class:`amrst.neighbours.NearestTree` on ``tgt``, reused when given;
    ``nearest`` a NearestCache of an earlier scale with a larger distance, reused
    when given.
    """
    from amrst.neighbours import NearestTree

    if tree is None:
        tree = NearestTree(tgt)
    if nearest is None or nearest.reach < 1.5 * max_dist:
        nearest = NearestCache(tree, tgt, len(src), max_dist)
    nearest.max_dist = max_dist
    T, lam, prev = T_init.copy(), 1e-3, np.inf
    for it in range(1, iters + 1):
        reporter.check_cancelled()
        p = src @ T[:3, :3].T + T[:3, 3]
        ok, q = nearest.match(p)
        if len(ok) < 6:
            return T, it, False
        p = p[ok]
        e = p - q
        # JᵀJ and Jᵀe of J_i = [-[p_i]x, I] (left increment) in closed form from sums,
        # instead of building the (N, 3, 6) Jacobian: H = [[Σ|p|²I - Σppᵀ, [Σp]x],
        # [-[Σp]x, N I]], g = [Σ p × e, Σ e]. The three column sums in one pass over
        # an (N, 9) buffer, p × e written out as np.cross computes it: the same sums
        # bit for bit (numpy adds the rows in order either way), and faster.
        w = np.empty((len(p), 9))
        w[:, :3] = p
        w[:, 3:6] = e
        for k, (a, b) in enumerate(((1, 2), (2, 0), (0, 1))):
            np.multiply(p[:, a], e[:, b], out=w[:, 6 + k])
            w[:, 6 + k] -= p[:, b] * e[:, a]
        sums = w.sum(axis=0)
        sp = sums[:3]
        sx = np.array(
            [[0.0, -sp[2], sp[1]], [sp[2], 0.0, -sp[0]], [-sp[1], sp[0], 0.0]]
        )
        H = np.empty((6, 6))
        H[:3, :3] = np.eye(3) * np.einsum("ni,ni->", p, p) - p.T @ p
        H[:3, 3:] = sx
        H[3:, :3] = -sx
        H[3:, 3:] = np.eye(3) * len(p)
        g = np.concatenate([sums[6:], sums[3:6]])
        # Not e @ e: OpenBLAS splits a long dot product over its threads, which
        # costs more than the product itself when the cores are busy, and makes the
        # last bits of the sum depend on the thread count.
        cost = float(np.einsum("ij,ij->", e, e)) / len(p)
        for _ in range(10):  # LM: raise damping until the step lowers the cost
            dx = np.linalg.solve(H + lam * np.diag(np.diag(H)), -g)
            dT = make_transform(rotvec_matrix(dx[:3]), dx[3:])
            off = p @ dT[:3, :3].T + dT[:3, 3] - q
            if np.mean(np.einsum("ij,ij->i", off, off)) < cost:
                lam = max(lam / 10, 1e-9)
                T = dT @ T
                break
            lam *= 10
        if abs(prev - cost) <= tol * max(cost, 1e-12):
            return T, it, True
        prev = cost
    return T, iters, False


def _robust_plane(
    src: np.ndarray,
    tgt: np.ndarray,
    T_init: Transform,
    max_dist: float,
    iters: int,
    tol: float,
) -> tuple[Transform, int, bool]:
    import open3d as o3d

    from amrst.guards import SOURCE, TARGET, require_points

    reg = o3d.pipelines.registration
    # Open3D's point-to-plane ICP raises its own multi-line error on a target of no
    # points (it has no normals): refused here with one line.
    s = o3d.geometry.PointCloud(
        o3d.utility.Vector3dVector(np.array(require_points(src, SOURCE)))
    )
    t = o3d.geometry.PointCloud(
        o3d.utility.Vector3dVector(np.array(require_points(tgt, TARGET)))
    )
    t.estimate_normals(
        o3d.geometry.KDTreeSearchParamHybrid(radius=max(max_dist, 0.05), max_nn=20)
    )
    est = reg.TransformationEstimationPointToPlane(reg.TukeyLoss(k=max_dist / 2))
    crit = reg.ICPConvergenceCriteria(
        relative_fitness=tol, relative_rmse=tol, max_iteration=iters
    )
    out = reg.registration_icp(s, t, max_dist, T_init, est, crit)
    T = np.asarray(out.transformation)
    # Open3D does not report iterations or convergence: one more iteration tells
    # whether the estimate still moves (converged when it moves < 0.1 mm / 0.001 deg).
    one = reg.registration_icp(
        s, t, max_dist, T, est, reg.ICPConvergenceCriteria(max_iteration=1)
    )
    step = np.linalg.inv(T) @ np.asarray(one.transformation)
    moved = (
        np.linalg.norm(step[:3, 3]) < 1e-4
        and np.arccos(np.clip((np.trace(step[:3, :3]) - 1) / 2, -1, 1)) < 1.75e-5
    )
    return T, iters, bool(moved)


def refine_registration(
    target_xyz: np.ndarray,
    source_xyz: np.ndarray,
    T_init: Transform,
    params: FineParams,
    reporter: Reporter = NULL_REPORTER,
    *,
    threads: int = THREADS,
) -> FineResult:
    """Refine a coarse ``T_target_source``.

    Parameters
    ----------
    target_xyz : (N, 3) float64
        Target points (target frame).
    source_xyz : (M, 3) float64
        Source points (source frame) chosen by ``params.points``.
    T_init : (4, 4) float64
        Coarse transform.
    params : FineParams
    reporter : Reporter
    threads : int
        Threads for the KD-tree queries.

    Returns
    -------
    FineResult
    """
    from amrst.neighbours import NearestTree
    from amrst.stages.voxels import voxel_sample

    if params.voxel_size_m > 0:
        source_xyz = source_xyz[voxel_sample(source_xyz, params.voxel_size_m)]
        target_xyz = target_xyz[voxel_sample(target_xyz, params.voxel_size_m)]
    all_source = source_xyz  # fitness and inlier RMSE are reported on all of them
    pick = None
    if 0 < params.max_points < len(source_xyz):
        pick = np.random.default_rng(0).choice(
            len(source_xyz), params.max_points, replace=False
        )
        source_xyz = source_xyz[np.sort(pick)]
    T = np.asarray(T_init, float).copy()
    tree = NearestTree(target_xyz, threads)  # for every scale and the final count
    ladder = _ladder(params)  # the correspondence distance of each scale
    nearest = NearestCache(tree, target_xyz, len(source_xyz), ladder[0])
    total, converged, dist = 0, True, params.max_corr_dist_m
    if params.method != "none":
        for s in range(params.scales):
            dist = ladder[s]
            if params.method == "lm_icp":
                T, it, conv = lm_icp(
                    source_xyz,
                    target_xyz,
                    T,
                    dist,
                    params.max_iterations,
                    params.tolerance,
                    reporter=reporter,
                    tree=tree,
                    nearest=nearest,
                )
            else:
                T, it, conv = _robust_plane(
                    source_xyz,
                    target_xyz,
                    T,
                    dist,
                    params.max_iterations,
                    params.tolerance,
                )
            total += it
            converged = conv
            reporter.progress(
                (s + 1) / params.scales,
                f"scale {s + 1}/{params.scales}, {dist * 100:.0f} cm",
            )
            reporter.check_cancelled()
    moved = all_source @ T[:3, :3].T + T[:3, 3]
    d = np.full(len(moved), np.inf)
    ask = np.ones(len(moved), dtype=bool)
    if params.method == "lm_icp":
        # The fitted points' nearest partners are still known (few are stale after
        # the last small step): only those within the last distance (a hair wider:
        # the tree's own distances decide below) are asked again. The distances stay
        # the tree's; the final count cost as much as the whole ICP before.
        fitted = np.arange(len(moved)) if pick is None else np.sort(pick)
        off = moved[fitted] - nearest.nearest(moved[fitted])
        ask[fitted] = np.einsum("ij,ij->i", off, off) < (dist * (1 + 1e-6)) ** 2
    d[ask] = tree.query(moved[ask])[0]
    inl = d < dist
    return FineResult(
        T,
        params.method,
        bool(converged),
        total,
        float(inl.mean()),
        float(np.sqrt(np.mean(d[inl] ** 2))) if inl.any() else float("nan"),
        dist,
    )
