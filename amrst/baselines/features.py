"""Global feature-based baselines: FPFH + RANSAC and FPFH + Fast Global Registration.

Both follow Open3D's global registration recipe: voxel downsampling, normals, FPFH
descriptors, a global estimate from descriptor matches, then point-to-plane ICP.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING, cast

import numpy as np

from amrst.baselines._common import (
    MethodResult,
    Stopwatch,
    finish,
    local_pair,
    to_o3d,
)
from amrst.errors import InvalidInput
from amrst.guards import SOURCE, TARGET

if TYPE_CHECKING:
    import open3d as o3d

    from amrst.types import Cloud, Transform


@dataclass(frozen=True, slots=True, kw_only=True)
class FeatureParams:
    """Settings of the FPFH baselines.

    voxel_size_m : voxel of the clouds that get descriptors (m).
    normal_radius_factor, feature_radius_factor : search radii in voxels.
    ransac_iterations, ransac_confidence : RANSAC stopping rule.
    distance_factor : inlier distance of RANSAC / FGR in voxels.
    refine_dists_m : point-to-plane ICP correspondence distances, coarse to fine (m).
    refine_voxel_m : voxel of the clouds ICP refines on (m).
    seed : seeds Open3D's RANSAC for repeatable runs.
    """

    voxel_size_m: float = 0.08
    normal_radius_factor: float = 2.0
    feature_radius_factor: float = 5.0
    ransac_iterations: int = 100_000
    ransac_confidence: float = 0.999
    distance_factor: float = 1.5
    refine_dists_m: tuple[float, ...] = (0.2, 0.05)
    refine_voxel_m: float = 0.03
    seed: int = 0

    def __post_init__(self) -> None:
        if self.voxel_size_m <= 0 or self.refine_voxel_m <= 0:
            raise ValueError("voxel sizes must be > 0")


#: Fewest occupied voxels a cloud needs for FPFH and the global registration.
MIN_VOXELS = 4


def _with_normals(
    xyz: np.ndarray, voxel_m: float, radius_m: float, what: str
) -> o3d.geometry.PointCloud:
    import open3d as o3d

    pcd = to_o3d(xyz, voxel_m, what)
    pcd.estimate_normals(
        o3d.geometry.KDTreeSearchParamHybrid(radius=radius_m, max_nn=30)
    )
    return pcd


def _features(
    xyz: np.ndarray, params: FeatureParams, what: str
) -> tuple[o3d.geometry.PointCloud, o3d.pipelines.registration.Feature]:
    import open3d as o3d

    v = params.voxel_size_m
    pcd = _with_normals(xyz, v, params.normal_radius_factor * v, what)
    # Open3D's global steps need a few distinct points: FGR divides by the spread.
    if len(pcd.points) < MIN_VOXELS:
        raise InvalidInput(
            f"{what.capitalize()} fills {len(pcd.points)} voxel(s) of {v:g} m, too "
            "few for FPFH features: a cloud of one spot, or coordinates not in metres."
        )
    # open3d's stub marks ``indices`` required; it defaults to all points.
    fpfh = o3d.pipelines.registration.compute_fpfh_feature(  # type: ignore[call-arg]
        pcd,
        o3d.geometry.KDTreeSearchParamHybrid(
            radius=params.feature_radius_factor * v, max_nn=100
        ),
    )
    return pcd, fpfh


def refine_point_to_plane(
    target_xyz: np.ndarray,
    source_xyz: np.ndarray,
    T_init: Transform,
    params: FeatureParams,
) -> Transform:
    """Point-to-plane ICP from ``T_init`` over ``params.refine_dists_m``.

    Parameters
    ----------
    target_xyz, source_xyz : (N, 3), (M, 3) float64
    T_init : (4, 4) float64
    params : FeatureParams

    Returns
    -------
    (4, 4) float64
    """
    import open3d as o3d

    reg = o3d.pipelines.registration
    radius = 3.0 * params.refine_voxel_m
    tgt = _with_normals(target_xyz, params.refine_voxel_m, radius, TARGET)
    src = to_o3d(source_xyz, params.refine_voxel_m, SOURCE)
    T = np.asarray(T_init, dtype=float).copy()
    for dist in params.refine_dists_m:
        res = reg.registration_icp(
            src,
            tgt,
            dist,
            T,
            reg.TransformationEstimationPointToPlane(),
            reg.ICPConvergenceCriteria(
                relative_fitness=1e-6, relative_rmse=1e-6, max_iteration=30
            ),
        )
        T = np.asarray(res.transformation).copy()
    return cast("np.ndarray", T)


def global_ransac(
    target_xyz: np.ndarray, source_xyz: np.ndarray, params: FeatureParams
) -> Transform:
    """Run the global step of FPFH + RANSAC alone (no ICP), as a candidate source does.

    Parameters
    ----------
    target_xyz, source_xyz : (N, 3), (M, 3) float64
    params : FeatureParams

    Returns
    -------
    (4, 4) float64
    """
    tgt_pcd, tgt_fpfh = _features(target_xyz, params, TARGET)
    src_pcd, src_fpfh = _features(source_xyz, params, SOURCE)
    res = _global(tgt_pcd, src_pcd, tgt_fpfh, src_fpfh, params, "ransac")
    return cast("np.ndarray", np.asarray(res.transformation).copy())


def _global(
    tgt_pcd: o3d.geometry.PointCloud,
    src_pcd: o3d.geometry.PointCloud,
    tgt_fpfh: o3d.pipelines.registration.Feature,
    src_fpfh: o3d.pipelines.registration.Feature,
    params: FeatureParams,
    global_method: str,
) -> o3d.pipelines.registration.RegistrationResult:
    import open3d as o3d

    reg = o3d.pipelines.registration
    dist = params.distance_factor * params.voxel_size_m
    if global_method == "ransac":
        o3d.utility.random.seed(params.seed)
        return reg.registration_ransac_based_on_feature_matching(
            src_pcd,
            tgt_pcd,
            src_fpfh,
            tgt_fpfh,
            False,  # mutual filter off
            dist,
            reg.TransformationEstimationPointToPoint(False),
            3,
            [
                reg.CorrespondenceCheckerBasedOnEdgeLength(0.9),
                reg.CorrespondenceCheckerBasedOnDistance(dist),
            ],
            reg.RANSACConvergenceCriteria(
                params.ransac_iterations, params.ransac_confidence
            ),
        )
    return reg.registration_fgr_based_on_feature_matching(
        src_pcd,
        tgt_pcd,
        src_fpfh,
        tgt_fpfh,
        reg.FastGlobalRegistrationOption(maximum_correspondence_distance=dist),
    )


def _register(
    target: Cloud, source: Cloud, params: FeatureParams, global_method: str
) -> MethodResult:
    clock = Stopwatch()
    tgt, src, origin = local_pair(target, source)
    with clock.stage("features"):
        tgt_pcd, tgt_fpfh = _features(tgt, params, TARGET)
        src_pcd, src_fpfh = _features(src, params, SOURCE)
    with clock.stage(global_method):
        res = _global(tgt_pcd, src_pcd, tgt_fpfh, src_fpfh, params, global_method)
    T_global = np.asarray(res.transformation).copy()
    with clock.stage("refine"):
        T = refine_point_to_plane(tgt, src, T_global, params)
    return finish(
        tgt, src, T, origin, clock, extra={"global_fitness": float(res.fitness)}
    )


def register_fpfh_ransac(
    target: Cloud,
    source: Cloud,
    params: FeatureParams = FeatureParams(),
) -> MethodResult:
    """FPFH + RANSAC (Open3D, mutual filter off, seeded) + point-to-plane ICP.

    Parameters
    ----------
    target, source : Cloud
    params : FeatureParams

    Returns
    -------
    MethodResult
    """
    return _register(target, source, params, "ransac")


def register_fgr(
    target: Cloud,
    source: Cloud,
    params: FeatureParams = FeatureParams(),
) -> MethodResult:
    """FPFH + Fast Global Registration (Zhou et al. 2016, Open3D) + point-to-plane ICP.

    Parameters
    ----------
    target, source : Cloud
    params : FeatureParams

    Returns
    -------
    MethodResult
    """
    return _register(target, source, params, "fgr")
