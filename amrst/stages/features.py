"""Shared geometry helpers: k-nearest-neighbour covariance features and Otsu thresholds."""

from __future__ import annotations

from typing import Any, cast

import numpy as np


def shape_features(
    xyz: np.ndarray, neighbours: np.ndarray, ks: tuple[int, ...]
) -> list[dict[str, np.ndarray]]:
    """Local covariance features for several k from one neighbour list.

    Parameters
    ----------
    xyz : (N, 3) float64
    neighbours : (M, K) int
        Neighbour indices into ``xyz`` sorted by distance, K >= max(ks).
    ks : tuple of int
        Neighbourhood sizes (including the point itself); the products are formed
        once for the largest.

    Returns
    -------
    list of dict
        Per k: ``linearity``, ``planarity``, ``scattering`` ((λ1-λ2)/λ1, (λ2-λ3)/λ1,
        λ3/λ1) and ``curvature`` (λ3/Σλ), all (M,).
    """
    return [_shape(*cov) for cov in _covariances(xyz, neighbours, ks)]


# Neighbourhoods per pass of _covariances (4096 x 30 neighbours: about 8 MB of work).
COV_CHUNK = 4096


def _covariances(
    xyz: np.ndarray, idx: np.ndarray, ks: tuple[int, ...]
) -> list[tuple[np.ndarray, ...]]:
    """Compute the entries (a, b, c, d, e, f) of each neighbourhood's covariance, per k.

    Moments of the offsets from each neighbourhood's first point (the point itself):
    centimetre-sized numbers, so E[uuᵀ] - E[u]E[u]ᵀ loses nothing to cancellation, and
    the products are formed once and summed in runs for all k.

    The neighbours lie along the first axis, (K, M): each run is summed by adding
    whole (M,) rows in the order numpy's pairwise sum adds a row of (M, K), so the
    values are those of ``p[:, done:k].sum(axis=1)`` (bit for bit on numpy 2.x) at a
    third of the cost (numpy's per-row reduction of 10-30 numbers is slow).

    Neighbourhoods are taken ``COV_CHUNK`` at a time (every column is computed on its
    own, so the values do not change): the (9, K, M) working set of a whole scan
    leaves the caches; chunks keep it in them.
    """
    if len(idx) > COV_CHUNK:
        parts = [
            _covariances(xyz, idx[i : i + COV_CHUNK], ks)
            for i in range(0, len(idx), COV_CHUNK)
        ]
        return [
            tuple(np.concatenate([p[j][c] for p in parts]) for c in range(6))
            for j in range(len(ks))
        ]
    ks = tuple(min(k, idx.shape[1]) for k in ks)  # tiny clouds: fewer neighbours
    kmax = max(ks)
    m = len(idx)
    # (3, K, M) gathered with np.take: several times faster than fancy indexing.
    order = np.ascontiguousarray(np.asarray(idx)[:, :kmax].T)
    g = np.take(np.ascontiguousarray(xyz.T, dtype=np.float64), order, axis=1)
    g -= g[:, :1].copy()
    # The six products; the offsets are summed where they lie (not copied beside
    # the products first: the same sums, a fifth less time).
    prods = np.empty((6, kmax, m))
    x, y, z = g
    for i, (u, v) in enumerate(((x, x), (y, y), (z, z), (x, y), (x, z), (y, z))):
        np.multiply(u, v, out=prods[i])
    out: list[tuple[np.ndarray, ...]] = []
    s_off: Any = 0.0  # then (3, M)
    s_prod: Any = 0.0  # then (6, M)
    done = 0
    for k in sorted(set(ks)):
        s_off = s_off + pairwise_rows(g[:, done:k])
        s_prod = s_prod + pairwise_rows(prods[:, done:k])
        done = k
        mx, my, mz = (v / k for v in s_off)
        a, b, c, d, e, f = (v / k for v in s_prod)
        out.append(
            (
                a - mx * mx,
                b - my * my,
                c - mz * mz,
                d - mx * my,
                e - mx * mz,
                f - my * mz,
            )
        )
    by_k = dict(zip(sorted(set(ks)), out, strict=True))
    return [by_k[k] for k in ks]


def pairwise_rows(a: np.ndarray) -> np.ndarray:
    """Sum (P, n, M) over its middle axis in numpy's pairwise order for one row.

    numpy sums a contiguous run of n numbers with 8 partial sums (for 8 <= n <= 128;
    halves first above 128, one by one below 8); doing the same with whole rows gives
    the same rounding for every column.
    """
    n = a.shape[1]
    res: np.ndarray
    if n < 8:
        res = np.zeros((a.shape[0], a.shape[2]))
        for i in range(n):
            res += a[:, i]
        return res
    if n > 128:
        half = n // 2
        half -= half % 8
        both: np.ndarray = pairwise_rows(a[:, :half]) + pairwise_rows(a[:, half:])
        return both
    r = a[:, :8].copy()
    stop = n - n % 8
    for i in range(8, stop, 8):
        r += a[:, i : i + 8]
    res = (r[:, 0] + r[:, 1]) + (r[:, 2] + r[:, 3])
    res += (r[:, 4] + r[:, 5]) + (r[:, 6] + r[:, 7])
    for i in range(stop, n):
        res += a[:, i]
    return res


def _shape(
    a: np.ndarray,
    b: np.ndarray,
    c: np.ndarray,
    d: np.ndarray,
    e: np.ndarray,
    f: np.ndarray,
) -> dict[str, np.ndarray]:
    l1, l2, l3 = _sym3_eigenvalues(a, b, c, d, e, f)
    l1, l2, l3 = (np.clip(v, 1e-12, None) for v in (l1, l2, l3))
    return {
        "linearity": (l1 - l2) / l1,
        "planarity": (l2 - l3) / l1,
        "scattering": l3 / l1,
        "curvature": l3 / (l1 + l2 + l3),
    }


def _sym3_eigenvalues(
    a: np.ndarray,
    b: np.ndarray,
    c: np.ndarray,
    d: np.ndarray,
    e: np.ndarray,
    f: np.ndarray,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Eigenvalues (descending) of symmetric 3x3 [[a, d, e], [d, b, f], [e, f, c]], batched."""
    q = (a + b + c) / 3
    p1 = d * d + e * e + f * f
    p2 = (a - q) ** 2 + (b - q) ** 2 + (c - q) ** 2 + 2 * p1
    p = np.sqrt(np.maximum(p2 / 6, 1e-300))
    ba, bb, bc = (a - q) / p, (b - q) / p, (c - q) / p
    bd, be, bf = d / p, e / p, f / p
    det = ba * (bb * bc - bf * bf) - bd * (bd * bc - bf * be) + be * (bd * bf - bb * be)
    phi = np.arccos(np.clip(det / 2, -1.0, 1.0)) / 3
    l1 = q + 2 * p * np.cos(phi)
    l3 = q + 2 * p * np.cos(phi + 2 * np.pi / 3)
    return l1, 3 * q - l1 - l3, l3


def otsu_threshold(values: np.ndarray, bins: int = 128) -> float:
    """Otsu's threshold of a 1-D sample (the split that maximises between-class variance)."""
    values = values[np.isfinite(values)]
    if len(values) == 0 or values.min() == values.max():
        return float(values[0]) if len(values) else 0.0
    hist, edges = np.histogram(values, bins=bins)
    centres = (edges[:-1] + edges[1:]) / 2
    w0 = np.cumsum(hist)
    w1 = w0[-1] - w0
    m0 = np.cumsum(hist * centres) / np.maximum(w0, 1)
    m1 = (np.sum(hist * centres) - np.cumsum(hist * centres)) / np.maximum(w1, 1)
    between = w0 * w1 * (m0 - m1) ** 2
    return float(centres[int(np.argmax(between[:-1]))])


def connected_components(xyz: np.ndarray, radius: float) -> np.ndarray:
    """Labels (N,) of the components linking points closer than ``radius``."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components as cc
    from scipy.spatial import cKDTree

    pairs = cKDTree(xyz).query_pairs(radius, output_type="ndarray")
    n = len(xyz)
    graph = coo_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])), shape=(n, n))
    return cast("np.ndarray", cc(graph, directed=False)[1])


def voxel_components(keys: np.ndarray) -> np.ndarray:
    """Labels (V,) of the 26-connected components of distinct integer voxels.

    The same labels as ``connected_components(keys.astype(float), 1.75)`` (voxels
    touching by a face, an edge or a corner), found by looking up the 13 forward
    neighbours of each voxel among the sorted voxel codes instead of a KD-tree pair
    search, which is faster.

    Parameters
    ----------
    keys : (V, 3) int64
        Distinct voxel indices (outside [0, 2^20 - 1) the KD-tree search is used).
    """
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components as cc

    n = len(keys)
    if n == 0:
        return np.zeros(0, dtype=np.int32)
    if keys.min() < 0 or keys.max() >= (1 << 20) - 1:  # codes would overflow
        return connected_components(keys.astype(float), 1.75)
    k = keys.astype(np.int64) + 1  # room for the -1 offsets
    code = (k[:, 0] << 42) | (k[:, 1] << 21) | k[:, 2]
    order = np.argsort(code)
    sorted_code = code[order]
    rows, cols = [], []
    for dx, dy, dz in _FORWARD_26:
        want = code + ((dx << 42) + (dy << 21) + dz)
        pos = np.minimum(np.searchsorted(sorted_code, want), n - 1)
        hit = np.flatnonzero(sorted_code[pos] == want)
        rows.append(hit)
        cols.append(order[pos[hit]])
    r, c = np.concatenate(rows), np.concatenate(cols)
    graph = coo_matrix((np.ones(len(r)), (r, c)), shape=(n, n))
    return cast("np.ndarray", cc(graph, directed=False)[1])


# Half of the 26 neighbour offsets: each pair of touching voxels is linked once.
_FORWARD_26 = [
    (dx, dy, dz)
    for dx in (-1, 0, 1)
    for dy in (-1, 0, 1)
    for dz in (-1, 0, 1)
    if (dx, dy, dz) > (0, 0, 0)
]
