"""ICP baselines: Open3D point-to-point ICP from the identity or from matched centroids.

The paper's ICP baseline starts from the scans as they are (identity). ``icp_centroid``
first moves the source centroid onto the target centroid, the cheapest sensible guess.
Both run coarse-to-fine over shrinking correspondence distances on 0.05 m voxel clouds.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import cast

import numpy as np

from amrst.baselines._common import (
    MethodResult,
    Stopwatch,
    finish,
    local_pair,
    to_o3d,
)
from amrst.guards import SOURCE, TARGET
from amrst.types import Cloud, Transform, make_transform


@dataclass(frozen=True, slots=True, kw_only=True)
class IcpParams:
    """Point-to-point ICP settings.

    voxel_size_m : voxel of the downsampled clouds (m).
    max_corr_dists_m : correspondence distance of each coarse-to-fine level (m).
    max_iterations : iterations of each level.
    """

    voxel_size_m: float = 0.05
    max_corr_dists_m: tuple[float, ...] = (1.0, 0.2, 0.05)
    max_iterations: tuple[int, ...] = (60, 40, 30)

    def __post_init__(self) -> None:
        if self.voxel_size_m <= 0:
            raise ValueError("voxel_size_m must be > 0")
        if len(self.max_corr_dists_m) != len(self.max_iterations):
            raise ValueError("one iteration count per correspondence distance")


def icp_point_to_point(
    target_xyz: np.ndarray,
    source_xyz: np.ndarray,
    T_init: Transform,
    params: IcpParams,
    clock: Stopwatch,
) -> Transform:
    """Coarse-to-fine point-to-point ICP on voxel-downsampled clouds.

    Parameters
    ----------
    target_xyz, source_xyz : (N, 3), (M, 3) float64
    T_init : (4, 4) float64
        Start of the source-to-target transform.
    params : IcpParams
    clock : Stopwatch
        Receives the stages ``downsample`` and ``icp``.

    Returns
    -------
    (4, 4) float64
        The source-to-target transform (Open3D does not report how many iterations
        each level used, so neither do we).
    """
    import open3d as o3d

    reg = o3d.pipelines.registration
    with clock.stage("downsample"):
        tgt = to_o3d(target_xyz, params.voxel_size_m, TARGET)
        src = to_o3d(source_xyz, params.voxel_size_m, SOURCE)
    T = np.asarray(T_init, dtype=float).copy()
    with clock.stage("icp"):
        for dist, iters in zip(
            params.max_corr_dists_m, params.max_iterations, strict=True
        ):
            criteria = reg.ICPConvergenceCriteria(
                relative_fitness=1e-6, relative_rmse=1e-6, max_iteration=iters
            )
            res = reg.registration_icp(
                src, tgt, dist, T, reg.TransformationEstimationPointToPoint(), criteria
            )
            T = np.asarray(res.transformation).copy()
    return cast("np.ndarray", T)


def _run(
    target: Cloud, source: Cloud, params: IcpParams, centroid: bool
) -> MethodResult:
    clock = Stopwatch()
    tgt, src, origin = local_pair(target, source)
    T_init = np.eye(4)
    if centroid:
        T_init = make_transform(np.eye(3), tgt.mean(axis=0) - src.mean(axis=0))
    T = icp_point_to_point(tgt, src, T_init, params, clock)
    return finish(tgt, src, T, origin, clock)


def register_icp(
    target: Cloud,
    source: Cloud,
    params: IcpParams = IcpParams(),
) -> MethodResult:
    """Point-to-point ICP from the identity (the paper's ICP baseline).

    Parameters
    ----------
    target, source : Cloud
    params : IcpParams

    Returns
    -------
    MethodResult
    """
    return _run(target, source, params, centroid=False)


def register_icp_centroid(
    target: Cloud,
    source: Cloud,
    params: IcpParams = IcpParams(),
) -> MethodResult:
    """Point-to-point ICP after moving the source centroid onto the target centroid.

    Parameters
    ----------
    target, source : Cloud
    params : IcpParams

    Returns
    -------
    MethodResult
    """
    return _run(target, source, params, centroid=True)
