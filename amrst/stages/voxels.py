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
    f = xyz - column_min(xyz)
    f /= voxel
    k = np.floor(f, out=f).astype(np.int64)
    del f
    if k.size and k.max() < (1 << 21):
        code = k[:, 0] << 42
        code |= k[:, 1] << 21
        code |= k[:, 2]
        return k, code
    return k, np.unique(k, axis=0, return_inverse=True)[1].ravel().astype(np.int64)


def sorted_unique(values: np.ndarray) -> np.ndarray:
    """Return the distinct integers of a 1-D array, sorted: ``np.unique(values)``.

    By a sort: numpy 2.3 and later answer a plain ``np.unique`` of integers from a hash
    table, much slower than a sort on voxel codes. (Unlike ``np.unique`` it keeps
    every NaN of a float array.)
    """
    ordered = np.sort(np.asarray(values).ravel())
    if len(ordered) < 2:
        return ordered
    first = np.empty(len(ordered), dtype=bool)
    first[0] = True
    np.not_equal(ordered[1:], ordered[:-1], out=first[1:])
    return ordered[first]


def column_min(a: np.ndarray) -> np.ndarray:
    """``a.min(axis=0)`` of an (N, D) array, one column at a time.

    The same values (a minimum is exact); numpy reduces a C-ordered (N, 3) array
    across rows much slower than each strided column.
    """
    return np.array([a[:, d].min() for d in range(a.shape[1])], dtype=a.dtype)


def finite_rows(a: np.ndarray) -> np.ndarray:
    """``np.isfinite(a).all(axis=1)`` of an (N, D) array, one column at a time.

    Faster than the 2-D reduction, for the same reason as :func:`column_min`.
    """
    finite: np.ndarray = np.isfinite(a[:, 0])
    for d in range(1, a.shape[1]):
        finite &= np.isfinite(a[:, d])
    return finite


def _packed_codes(xyz: np.ndarray, voxel: float) -> np.ndarray | None:
    """Compute voxel_grid's codes column by column; None when they do not pack."""
    lo = column_min(xyz)
    code = np.zeros(len(xyz), dtype=np.int64)
    for d, shift in ((0, 42), (1, 21), (2, 0)):
        k = np.floor((xyz[:, d] - lo[d]) / voxel).astype(np.int64)
        if k.max() >= (1 << 21):
            return None
        k <<= shift
        code |= k
    return code


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
    return _representatives(xyz, voxel, with_owner=False)[0]


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
    return _representatives(xyz, voxel, with_owner=True)


def _representatives(
    xyz: np.ndarray, voxel: float, *, with_owner: bool
) -> tuple[np.ndarray, np.ndarray]:
    """Return :func:`voxel_representatives`; the owners only when asked.

    :func:`voxel_sample` drops them (empty): a gather over every point saved.
    """
    if len(xyz) == 0:
        return np.zeros(0, dtype=np.int64), np.zeros(0, dtype=np.int64)
    code = _packed_codes(xyz, voxel)
    if code is None:
        code = voxel_grid(xyz, voxel)[1]
    # An unstable sort groups the points by voxel (faster than a stable one: SIMD
    # sorts); every sum below runs over the points in index order (bincount over the
    # unsorted points), so the centroids, and the choice, are bit for bit those of a
    # stable grouping.
    order = np.argsort(code)
    sorted_code = code[order]
    new = np.empty(len(order), dtype=bool)
    new[0] = True
    np.not_equal(sorted_code[1:], sorted_code[:-1], out=new[1:])
    n = int(np.count_nonzero(new))
    group = np.empty(len(xyz), dtype=np.int64)  # voxel of each point
    group[order] = np.cumsum(new) - 1
    del order, sorted_code, new
    counts = np.bincount(group, minlength=n)
    # Column by column: no (N, 3) temporaries at millions of points; the same
    # operations in the same order as np.sum((xyz - mean[group]) ** 2, axis=1).
    dist = np.zeros(len(xyz))
    for d in range(3):
        mean = np.bincount(group, xyz[:, d], n) / counts
        off = xyz[:, d] - mean[group]
        off *= off
        dist += off
    nearest = np.full(n, np.inf)
    np.minimum.at(nearest, group, dist)
    hit = np.flatnonzero(dist == nearest[group])
    rep_of_group = np.full(n, len(xyz), dtype=np.int64)
    np.minimum.at(rep_of_group, group[hit], hit)  # ties: the lowest index
    if not with_owner:
        return np.sort(rep_of_group), np.zeros(0, dtype=np.int64)
    by_index = np.argsort(rep_of_group)
    reps = rep_of_group[by_index]
    rank = np.empty(n, dtype=np.int64)
    rank[by_index] = np.arange(n)
    return reps, rank[group]
