"""Baseline registration methods behind one interface, for the benchmark.

Every method is a ``Method``: ``method(target, source) -> MethodResult``. ``METHODS``
names them: the paper's ICP and NDT baselines (both from the identity), ICP from
matched centroids, two global feature methods (FPFH + RANSAC, FPFH + FGR),
KISS-Matcher (with the same point-to-plane polish, and with small_gicp's GICP), and
``amrst`` itself.
"""

from __future__ import annotations

from amrst.baselines._common import EVAL_DIST_M, Method, MethodResult
from amrst.baselines.amrst_method import register_amrst
from amrst.baselines.features import FeatureParams, register_fgr, register_fpfh_ransac
from amrst.baselines.icp import IcpParams, register_icp, register_icp_centroid
from amrst.baselines.kiss_matcher import (
    KissParams,
    register_kiss_gicp,
    register_kiss_matcher,
)
from amrst.baselines.ndt import NdtParams, register_ndt

METHODS: dict[str, Method] = {
    "icp": register_icp,
    "icp_centroid": register_icp_centroid,
    "ndt": register_ndt,
    "fpfh_ransac": register_fpfh_ransac,
    "fgr": register_fgr,
    "kiss_matcher": register_kiss_matcher,
    "kiss_gicp": register_kiss_gicp,
    "amrst": register_amrst,
}

__all__ = [
    "EVAL_DIST_M",
    "METHODS",
    "FeatureParams",
    "IcpParams",
    "KissParams",
    "Method",
    "MethodResult",
    "NdtParams",
    "register_amrst",
    "register_fgr",
    "register_fpfh_ransac",
    "register_icp",
    "register_icp_centroid",
    "register_kiss_gicp",
    "register_kiss_matcher",
    "register_ndt",
]
