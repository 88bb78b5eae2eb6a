"""Voxel grids and one real point per voxel, shared by every stage that thins.

Preprocessing, the skeleton, verification, the trunk search and fine registration all
thin a cloud the same way: the point nearest each occupied voxel's centroid, so the
thinned cloud holds real points and indices into the original.
"""

from __future__ import annotations

import numpy as np


def voxel_grid(xyz: np.ndarray, voxel: float) -> tuple[np.ndarray, np.ndarray]:
    """Integer voxel of each point, and one int64 code per voxel (for a fast 1-D unique).

    Returns
    -------
    keys : (N, 3) int64, counted from the cloud's minimum corner
    code : (N,) int64, equal for points in the same voxel. Keys of up to 2^21 voxels per
        axis are packed into one int64; larger grids fall back to row-wise codes.
    """
    k = np.floor((xyz - xyz.min(axis=0)) / voxel).astype(np.int64)
    if k.size and k.max() < (1 << 21):
        return k, (k[:, 0] << 42) | (k[:, 1] << 21) | k[:, 2]
    return k, np.unique(k, axis=0, return_inverse=True)[1].ravel().astype(np.int64)


def voxel_sample(xyz: np.ndarray, voxel: float) -> np.ndarray:
    """Index of the point nearest each occupied voxel's centroid (keeps real points).

    Parameters
    ----------
    xyz : (N, 3) float64
    voxel : float
        Voxel size (m).

    Returns
    -------
    (V,) int64
        Sorted indices of the representatives (see :func:`voxel_representatives`).
    """
    return voxel_representatives(xyz, voxel)[0]


def voxel_representatives(
    xyz: np.ndarray, voxel: float
) -> tuple[np.ndarray, np.ndarray]:
    """One real point per occupied voxel: the one nearest the voxel's centroid.

    Parameters
    ----------
    xyz : (N, 3) float64
    voxel : float
        Voxel size (m).

    Returns
    -------
    reps : (V,) int64, sorted
        Index of each voxel's representative (ties go to the lowest index).
    owner : (N,) int64
        Position in ``reps`` of the representative of each point's voxel.
    """
    if len(xyz) == 0:
        return np.zeros(0, dtype=np.int64), np.zeros(0, dtype=np.int64)
    code = voxel_grid(xyz, voxel)[1]
    # One stable sort groups the points by voxel; within a voxel they stay in index
    # order, so the centroid sums run as a bincount over the unsorted points would.
    order = np.argsort(code, kind="stable")
    sorted_code = code[order]
    new = np.empty(len(order), dtype=bool)
    new[0] = True
    np.not_equal(sorted_code[1:], sorted_code[:-1], out=new[1:])
    group = np.cumsum(new) - 1  # voxel of each sorted point
    n = int(group[-1]) + 1
    pts = xyz[order]
    counts = np.bincount(group, minlength=n)
    centroids = np.column_stack([np.bincount(group, pts[:, d], n) for d in range(3)])
    dist = np.sum((pts - centroids[group] / counts[group, None]) ** 2, axis=1)
    nearest = np.minimum.reduceat(dist, np.flatnonzero(new))
    hit = np.flatnonzero(dist == nearest[group])  # sorted position, by voxel then index
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
