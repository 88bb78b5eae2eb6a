"""The fine stage's final count asks the KD-tree only for points that may be inliers:
its fitness and inlier RMSE equal, bit for bit, those of one query of every point."""

from __future__ import annotations

import numpy as np
import pytest

from amrst.neighbours import NearestTree
from amrst.stages.fine import FineParams, refine_registration
from amrst.types import make_transform


def _pair() -> tuple[np.ndarray, np.ndarray]:
    """A target of three noisy planes and a source that overlaps half of it, 2 cm off."""
    rng = np.random.default_rng(7)
    u = rng.uniform(0.0, 3.0, (6000, 2))
    planes = [
        np.column_stack([u[:2000, 0], u[:2000, 1], np.zeros(2000)]),
        np.column_stack([u[2000:4000, 0], np.zeros(2000), u[2000:4000, 1]]),
        np.column_stack([np.zeros(2000), u[4000:, 0], u[4000:, 1]]),
    ]
    tgt = np.vstack(planes) + rng.normal(0.0, 0.004, (6000, 3))
    src = tgt[rng.choice(6000, 2500, replace=False)] + rng.normal(0.0, 0.004, (2500, 3))
    src = np.vstack([src, rng.uniform(3.5, 6.0, (800, 3))])  # points off the target
    return tgt, src + np.array([0.02, -0.01, 0.015])


@pytest.mark.parametrize("max_points", [0, 500])
@pytest.mark.parametrize("voxel", [0.0, 0.05])
def test_fitness_and_rmse_equal_one_query_of_every_point(max_points, voxel) -> None:
    from amrst.stages.voxels import voxel_sample

    tgt, src = _pair()
    params = FineParams(voxel_size_m=voxel, max_points=max_points, scales=2)
    res = refine_registration(tgt, src, make_transform(np.eye(3), np.zeros(3)), params)
    if voxel > 0:  # what the stage thins to
        src, tgt = src[voxel_sample(src, voxel)], tgt[voxel_sample(tgt, voxel)]
    T = res.T_target_source
    d = NearestTree(tgt).query(src @ T[:3, :3].T + T[:3, 3])[0]  # the former count
    inl = d < res.max_corr_dist_m
    assert 0.3 < inl.mean() < 1.0  # inliers and outliers both present
    assert res.fitness == float(inl.mean())
    assert res.inlier_rmse_m == float(np.sqrt(np.mean(d[inl] ** 2)))
