"""KISS-Matcher (Lim et al. 2025) as a baseline: the strongest pip-installable global matcher.

KISS-Matcher finds a global pose from Faster-PFH correspondences pruned by a
graph-theoretic outlier rejection and a robust (GNC-TLS) solver. Its wheels exist for
Linux x86_64 and macOS arm64 (``pyproject.toml`` installs it there only); elsewhere
``kiss_matcher_available()`` is False and the FPFH + RANSAC global step stands in.

Two fine steps follow it here: ``register_kiss_matcher`` uses the same point-to-plane
ICP as the other feature baselines (``features.refine_point_to_plane``), and
``register_kiss_gicp`` uses small_gicp's GICP, the peer the benchmark compares with
("KISS-Matcher + GICP": ``KISSMatcherConfig(0.1)``, then GICP at 2 cm, 0.2 m).
"""

from __future__ import annotations

import importlib.util
from dataclasses import dataclass
from typing import TYPE_CHECKING

from amrst.baselines._common import MethodResult, Stopwatch, finish, local_pair
from amrst.guards import grid_pair
from amrst.stages.global_match import kiss_global, kiss_matcher_available

if TYPE_CHECKING:
    import numpy as np

    from amrst.types import Cloud, Transform


@dataclass(frozen=True, slots=True, kw_only=True)
class KissParams:
    """Settings of the KISS-Matcher baselines.

    voxel_size_m : KISS-Matcher's voxel (its Faster-PFH radii scale with it).
    gicp_voxel_m, gicp_max_dist_m : small_gicp GICP downsampling and correspondence
        distance.
    """

    voxel_size_m: float = 0.1
    gicp_voxel_m: float = 0.02
    gicp_max_dist_m: float = 0.2

    def __post_init__(self) -> None:
        if self.voxel_size_m <= 0 or self.gicp_voxel_m <= 0:
            raise ValueError("voxel sizes must be > 0")


def small_gicp_available() -> bool:
    """Tell whether the ``small_gicp`` package can be imported here."""
    return importlib.util.find_spec("small_gicp") is not None


def refine_gicp(
    target_xyz: np.ndarray,
    source_xyz: np.ndarray,
    T_init: Transform,
    params: KissParams,
) -> Transform:
    """small_gicp GICP from ``T_init`` (2 threads).

    small_gicp ends the process on an empty target and drops points beyond its voxel
    grid silently: the clouds pass :func:`~amrst.guards.grid_pair` first.

    Returns
    -------
    (4, 4) float64

    Raises
    ------
    InvalidInput
        An empty cloud, NaN/inf coordinates, or a span the voxel grid cannot hold.
    """
    import small_gicp

    pair = grid_pair(target_xyz, source_xyz, params.gicp_voxel_m)
    res = small_gicp.align(
        pair.target,
        pair.source,
        pair.shift(T_init),
        registration_type="GICP",
        downsampling_resolution=params.gicp_voxel_m,
        max_correspondence_distance=params.gicp_max_dist_m,
        num_threads=2,
    )
    return pair.unshift(res.T_target_source)


def _global(
    tgt: np.ndarray, src: np.ndarray, params: KissParams
) -> tuple[Transform, dict[str, float]]:
    if kiss_matcher_available():
        # as shipped, on its own threads (our pipeline holds it to one)
        T, inliers = kiss_global(tgt, src, params.voxel_size_m, one_thread=False)
        return T, {"kiss_inliers": float(inliers), "fallback": 0.0}
    # Where no wheel exists: Open3D FPFH + RANSAC's global step instead.
    from amrst.baselines.features import FeatureParams, global_ransac

    return global_ransac(tgt, src, FeatureParams()), {"fallback": 1.0}


def register_kiss_matcher(
    target: Cloud, source: Cloud, params: KissParams = KissParams()
) -> MethodResult:
    """KISS-Matcher, then point-to-plane ICP (the fine step of the FPFH baselines).

    Parameters
    ----------
    target, source : Cloud
    params : KissParams

    Returns
    -------
    MethodResult
    """
    from amrst.baselines.features import FeatureParams, refine_point_to_plane

    clock = Stopwatch()
    tgt, src, origin = local_pair(target, source)
    with clock.stage("kiss_matcher"):
        T_global, extra = _global(tgt, src, params)
    with clock.stage("refine"):
        T = refine_point_to_plane(tgt, src, T_global, FeatureParams())
    return finish(tgt, src, T, origin, clock, extra=extra)


def register_kiss_gicp(
    target: Cloud, source: Cloud, params: KissParams = KissParams()
) -> MethodResult:
    """KISS-Matcher, then small_gicp GICP (point-to-plane ICP where it is missing).

    Parameters
    ----------
    target, source : Cloud
    params : KissParams

    Returns
    -------
    MethodResult
    """
    clock = Stopwatch()
    tgt, src, origin = local_pair(target, source)
    with clock.stage("kiss_matcher"):
        T_global, extra = _global(tgt, src, params)
    with clock.stage("gicp"):
        if small_gicp_available():
            T = refine_gicp(tgt, src, T_global, params)
        else:
            from amrst.baselines.features import FeatureParams, refine_point_to_plane

            T = refine_point_to_plane(tgt, src, T_global, FeatureParams())
    return finish(tgt, src, T, origin, clock, extra=extra)
