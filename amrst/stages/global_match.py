"""A generic global matcher: a third source of coarse candidates, blind to tree structure.

KISS-Matcher (Faster-PFH features, graph-based outlier pruning, a robust solver) where
its wheel exists (Linux x86_64, macOS arm64); Open3D FPFH + RANSAC elsewhere, or when
``matcher`` asks for it. It runs on the points the tree stages use (the ground is
removed first: a ground plane is what generic features lock onto) and proposes one
pose, which the pipeline polishes and verifies like every other candidate
(``amrst.pipeline.features_source``).
"""

from __future__ import annotations

import contextlib
import time
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np

from amrst.guards import kiss_pair

if TYPE_CHECKING:
    from amrst.types import Transform

GLOBAL_MODES = ("fallback", "always", "off")
MATCHERS = ("auto", "kiss", "fpfh")


@dataclass(frozen=True, slots=True, kw_only=True)
class GlobalMatchParams:
    """The generic feature matcher."""

    mode: str = field(
        default="fallback",
        metadata={
            "choices": GLOBAL_MODES,
            "help": "fallback: ask it only when no tetrahedron match verifies (before the trunk search); always: add its pose to every ranking; off: never.",
        },
    )
    matcher: str = field(
        default="auto",
        metadata={
            "choices": MATCHERS,
            "help": "auto: KISS-Matcher where it is installed, else Open3D FPFH + RANSAC; kiss or fpfh to choose.",
        },
    )
    voxel_size_m: float = field(
        default=0.1,
        metadata={
            "unit": "m",
            "min": 0.02,
            "max": 2.0,
            "help": "Voxel of the clouds the matcher describes (its feature radii scale with it).",
        },
    )

    def __post_init__(self) -> None:
        if self.mode not in GLOBAL_MODES:
            raise ValueError(f"global_match mode must be one of {GLOBAL_MODES}")
        if self.matcher not in MATCHERS:
            raise ValueError(f"global_match matcher must be one of {MATCHERS}")


@dataclass(frozen=True, slots=True)
class GlobalMatchResult:
    """The matcher's pose and how it got it."""

    T_target_source: Transform  # (4, 4) local frames; identity when it found nothing
    found: bool
    method: str  # "kiss" or "fpfh"
    n_inliers: int  # final correspondences (KISS-Matcher); fitness x 1000 for RANSAC
    seconds: float


def kiss_matcher_available() -> bool:
    """Tell whether the ``kiss_matcher`` package can be imported here."""
    import importlib.util

    return importlib.util.find_spec("kiss_matcher") is not None


def kiss_global(
    target_xyz: np.ndarray,
    source_xyz: np.ndarray,
    voxel_size_m: float = 0.1,
    one_thread: bool = True,
) -> tuple[Transform, int]:
    """Global pose of the source on the target by KISS-Matcher.

    Parameters
    ----------
    target_xyz, source_xyz : (N, 3), (M, 3) float64
    voxel_size_m : float
    one_thread : bool
        Run it on one thread, so its pose is the same on every run (our pipeline).
        The benchmark's KISS-Matcher baseline runs it as shipped (False).

    Returns
    -------
    T_target_source : (4, 4) float64
        Identity when KISS-Matcher found no solution.
    n_inliers : int
        Its final inlier correspondences (0 = no solution).
    """
    import kiss_matcher

    from amrst.stages.kiss_threads import kiss_one_thread

    config = kiss_matcher.KISSMatcherConfig(voxel_size_m)
    # It ends the process on a cloud without feature points: no pose instead.
    pair = kiss_pair(target_xyz, source_xyz, voxel_size_m, config.normal_radius)
    if pair is None:
        return np.eye(4), 0
    matcher = kiss_matcher.KISSMatcher(config)
    # threads made its pose vary from run to run
    with kiss_one_thread() if one_thread else contextlib.nullcontext():
        sol = matcher.estimate(
            pair.source.astype(np.float32), pair.target.astype(np.float32)
        )
    if not sol.valid:
        return np.eye(4), 0
    T = np.eye(4)
    T[:3, :3] = np.asarray(sol.rotation, dtype=float)
    T[:3, 3] = np.asarray(sol.translation, dtype=float).reshape(3)
    return pair.unshift(T), int(matcher.get_num_final_inliers())


def match_globally(
    target_xyz: np.ndarray, source_xyz: np.ndarray, params: GlobalMatchParams
) -> GlobalMatchResult:
    """Estimate ``T_target_source`` from local shape features alone.

    Parameters
    ----------
    target_xyz, source_xyz : (N, 3), (M, 3) float64
        The points to match (local frames).
    params : GlobalMatchParams

    Returns
    -------
    GlobalMatchResult
    """
    t0 = time.perf_counter()
    use_kiss = params.matcher == "kiss" or (
        params.matcher == "auto" and kiss_matcher_available()
    )
    if use_kiss:
        T, inliers = kiss_global(target_xyz, source_xyz, params.voxel_size_m)
        return GlobalMatchResult(
            T, inliers > 0, "kiss", inliers, time.perf_counter() - t0
        )
    from dataclasses import replace

    from amrst.baselines.features import FeatureParams, global_ransac

    T = global_ransac(
        target_xyz,
        source_xyz,
        replace(FeatureParams(), voxel_size_m=params.voxel_size_m),
    )
    found = not np.allclose(T, np.eye(4))
    return GlobalMatchResult(T, found, "fpfh", int(found), time.perf_counter() - t0)
