"""Helpers shared by the baselines: result type, frames, Open3D conversion, quality."""

from __future__ import annotations

import time
from collections.abc import Callable, Iterator, Mapping
from contextlib import contextmanager
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, cast

import numpy as np

from amrst.guards import open3d_points
from amrst.types import Cloud, Transform, make_transform

if TYPE_CHECKING:
    import open3d as o3d

# Fitness and inlier RMSE of every method are measured the same way: the share of
# (0.05 m voxel) source points within this distance of the target after the move.
EVAL_DIST_M = 0.1


@dataclass(frozen=True, slots=True)
class MethodResult:
    """What a registration method returns to the benchmark.

    Attributes
    ----------
    T_target_source : (4, 4) float64
        Maps source world coordinates into target world coordinates.
    timings : dict of str to float
        Seconds per stage, always with ``"total"``.
    fitness : float
        Share of source points within ``EVAL_DIST_M`` of the target after the move.
    inlier_rmse_m : float
        RMS distance of those points (m).
    iterations : int or None
        Iterations of the last iterative stage, where that means something.
    converged : bool or None
        Whether the last iterative stage met its convergence test.
    extra : dict
        Method-specific numbers (e.g. ``confidence`` for amrst).
    """

    T_target_source: Transform
    timings: Mapping[str, float]
    fitness: float = float("nan")
    inlier_rmse_m: float = float("nan")
    iterations: int | None = None
    converged: bool | None = None
    extra: Mapping[str, Any] = field(default_factory=dict)


Method = Callable[[Cloud, Cloud], MethodResult]


class Stopwatch:
    """Collects wall times of named stages; ``total`` is added by :meth:`finish`."""

    def __init__(self) -> None:
        self._start = time.perf_counter()
        self.timings: dict[str, float] = {}

    @contextmanager
    def stage(self, name: str) -> Iterator[None]:
        """Time the block as stage ``name`` (times of repeated names add up)."""
        t0 = time.perf_counter()
        try:
            yield
        finally:
            self.timings[name] = self.timings.get(name, 0.0) + time.perf_counter() - t0

    def finish(self) -> dict[str, float]:
        """Return the stage times plus ``total`` since construction."""
        return {**self.timings, "total": time.perf_counter() - self._start}


def local_pair(
    target: Cloud, source: Cloud
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Both clouds relative to the target offset, so large offsets keep millimetres.

    Returns
    -------
    target_xyz, source_xyz : (N, 3), (M, 3) float64
    origin : (3,) float64
        The target offset; see :func:`to_world`.
    """
    origin = np.asarray(target.offset, dtype=float)
    return target.xyz, source.xyz + (source.offset - origin), origin


def to_world(T_local: Transform, origin: np.ndarray) -> Transform:
    """Turn a transform between origin-relative frames into a world ``T_target_source``."""
    shift = make_transform(np.eye(3), origin)
    back = make_transform(np.eye(3), -origin)
    return cast("np.ndarray", shift @ T_local @ back)


def to_local(T_world: Transform, origin: np.ndarray) -> Transform:
    """Invert :func:`to_world`: express a world transform in origin-relative frames."""
    return to_world(T_world, -np.asarray(origin, dtype=float))


def to_o3d(xyz: np.ndarray, voxel_m: float, what: str) -> o3d.geometry.PointCloud:
    """Make an Open3D point cloud of one centroid per ``voxel_m`` voxel of ``xyz``.

    The points are checked first (:func:`~amrst.guards.open3d_points`): Open3D
    raises its own multi-line RuntimeError on a span its voxel keys cannot hold, and
    its features and point-to-plane ICP on a cloud of no points.

    Parameters
    ----------
    xyz : (N, 3) array_like
    voxel_m : float
    what : str
        Names the cloud in a message, e.g. ``"the source scan"``.

    Raises
    ------
    InvalidInput
        No points, NaN/inf coordinates, or a span too wide for ``voxel_m`` voxels.
    """
    import open3d as o3d

    pcd = o3d.geometry.PointCloud()
    # a copy: Vector3dVector refuses read-only arrays such as Cloud.xyz
    pcd.points = o3d.utility.Vector3dVector(np.array(open3d_points(xyz, voxel_m, what)))
    return pcd.voxel_down_sample(voxel_m)


def voxel_down(xyz: np.ndarray, voxel_m: float) -> np.ndarray:
    """Voxel-grid downsampling (one centroid per occupied voxel), (K, 3) float64."""
    keys = np.floor(xyz / voxel_m).astype(np.int64)
    _, inverse, counts = np.unique(
        keys, axis=0, return_inverse=True, return_counts=True
    )
    inverse = inverse.reshape(-1)
    sums = np.zeros((len(counts), 3))
    np.add.at(sums, inverse, xyz)
    return sums / counts[:, None]


def evaluate(
    target_xyz: np.ndarray, source_xyz: np.ndarray, T_local: Transform
) -> tuple[float, float]:
    """Fitness and inlier RMSE (m) of a move, on 0.05 m voxel clouds within EVAL_DIST_M.

    Parameters
    ----------
    target_xyz, source_xyz : (N, 3), (M, 3) float64
    T_local : (4, 4) float64

    Returns
    -------
    fitness, inlier_rmse_m : float
    """
    from scipy.spatial import cKDTree

    tgt = voxel_down(target_xyz, 0.05)
    src = voxel_down(source_xyz, 0.05) @ T_local[:3, :3].T + T_local[:3, 3]
    if len(tgt) == 0 or len(src) == 0:
        return 0.0, float("nan")
    d = cKDTree(tgt).query(src, distance_upper_bound=EVAL_DIST_M)[0]
    inside = np.isfinite(d)
    rmse = float(np.sqrt(np.mean(d[inside] ** 2))) if inside.any() else float("nan")
    return float(inside.mean()), rmse


def finish(
    tgt: np.ndarray,
    src: np.ndarray,
    T_local: Transform,
    origin: np.ndarray,
    clock: Stopwatch,
    **fields: Any,
) -> MethodResult:
    """Stop ``clock``, score the move and wrap it as a world-frame MethodResult.

    The fitness below is not timed; ``fields`` are the remaining MethodResult fields.
    """
    timings = clock.finish()
    fitness, rmse = evaluate(tgt, src, T_local)
    return MethodResult(
        to_world(T_local, origin),
        timings,
        fitness=fitness,
        inlier_rmse_m=rmse,
        **fields,
    )
