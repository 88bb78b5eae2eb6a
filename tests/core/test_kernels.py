"""Fast kernels against the slow answers they replaced (reference code or brute force)."""

from __future__ import annotations

import numpy as np
import pytest

from amrst.stages.voxels import voxel_grid, voxel_representatives


def _reference_representatives(
    xyz: np.ndarray, voxel: float
) -> tuple[np.ndarray, np.ndarray]:
    """The stable-sort implementation voxel_representatives had before (kept verbatim)."""
    code = voxel_grid(xyz, voxel)[1]
    order = np.argsort(code, kind="stable")
    sorted_code = code[order]
    new = np.empty(len(order), dtype=bool)
    new[0] = True
    np.not_equal(sorted_code[1:], sorted_code[:-1], out=new[1:])
    group = np.cumsum(new) - 1
    n = int(group[-1]) + 1
    pts = xyz[order]
    counts = np.bincount(group, minlength=n)
    centroids = np.column_stack([np.bincount(group, pts[:, d], n) for d in range(3)])
    dist = np.sum((pts - centroids[group] / counts[group, None]) ** 2, axis=1)
    nearest = np.minimum.reduceat(dist, np.flatnonzero(new))
    hit = np.flatnonzero(dist == nearest[group])
    first = np.empty(len(hit), dtype=bool)
    first[0] = True
    np.not_equal(group[hit][1:], group[hit][:-1], out=first[1:])
    rep_of_group = order[hit[first]]
    by_index = np.argsort(rep_of_group)
    reps = rep_of_group[by_index]
    rank = np.empty(n, dtype=np.int64)
    rank[by_index] = np.arange(n)
    owner = np.empty(len(xyz), dtype=np.int64)
    owner[order] = rank[group]
    return reps, owner


@pytest.mark.parametrize("voxel", [0.01, 0.05, 0.3])
def test_voxel_representatives_equal_the_stable_sort_version(voxel: float) -> None:
    """Identical indices and owners, ties (exact duplicates, two-point voxels) included."""
    rng = np.random.default_rng(11)
    xyz = rng.normal(size=(40_000, 3)) * [1.0, 1.0, 4.0]
    xyz = np.vstack([xyz, xyz[:3000], xyz[:500]])  # duplicates, some tripled
    xyz = xyz[rng.permutation(len(xyz))]
    reps, owner = voxel_representatives(xyz, voxel)
    ref_reps, ref_owner = _reference_representatives(xyz, voxel)
    np.testing.assert_array_equal(reps, ref_reps)
    np.testing.assert_array_equal(owner, ref_owner)


def test_voxel_grid_codes_separate_voxels_on_a_huge_grid() -> None:
    """More than 2^21 voxels along an axis: the row-wise fallback still groups right."""
    xyz = np.array([[0.0, 0, 0], [0.0005, 0, 0], [5000.0, 0, 0], [5000.0004, 0, 0]])
    keys, code = voxel_grid(xyz, 0.001)
    assert keys[:, 0].max() >= 1 << 21
    assert code[0] == code[1] != code[2] == code[3]
    reps, owner = voxel_representatives(xyz, 0.001)
    assert len(reps) == 2
    np.testing.assert_array_equal(owner, [0, 0, 1, 1])
