"""Shared geometry helpers: k-nearest-neighbour covariance features and Otsu thresholds."""

from __future__ import annotations

import numpy as np


def eigen_features(
    xyz: np.ndarray, k: int, tree=None, neighbours=None
) -> dict[str, np.ndarray]:
    """Local covariance features on k nearest neighbours.

    Parameters
    ----------
    xyz : (N, 3) float64
    k : int
        Neighbourhood size (including the point itself).
    tree : scipy.spatial.cKDTree or None
        A tree built on ``xyz`` (reused when given).
    neighbours : (N, K) int or None
        Neighbour indices sorted by distance with K >= k (one query serves all scales).

    Returns
    -------
    dict
        ``linearity``, ``planarity``, ``scattering`` ((λ1-λ2)/λ1, (λ2-λ3)/λ1, λ3/λ1),
        ``curvature`` (λ3/Σλ), ``verticality`` (|z| of the principal direction), all (N,).
    """
    from scipy.spatial import cKDTree

    k = int(min(k, len(xyz)))
    if neighbours is not None and neighbours.shape[1] >= k:
        idx = neighbours[:, :k]
    else:
        if tree is None:
            tree = cKDTree(xyz)
        _, idx = tree.query(xyz, k=k, workers=-1)
    nb = xyz[idx]  # (N, k, 3)
    nb = nb - nb.mean(axis=1, keepdims=True)
    x, y, z = nb[..., 0], nb[..., 1], nb[..., 2]
    # The six covariance entries, then eigenvalues in closed form (Smith 1961): several
    # times faster than a batched eigh; the principal direction is solved only for the
    # verticality feature.
    a, b, c = (x * x).mean(1), (y * y).mean(1), (z * z).mean(1)
    d, e, f = (x * y).mean(1), (x * z).mean(1), (y * z).mean(1)
    l1, l2, l3 = _sym3_eigenvalues(a, b, c, d, e, f)
    l1, l2, l3 = (np.clip(v, 1e-12, None) for v in (l1, l2, l3))
    # Principal direction: a column of adj(C - l1 I) (the largest one for stability).
    m = np.stack(
        [
            np.stack([a - l1, d, e], -1),
            np.stack([d, b - l1, f], -1),
            np.stack([e, f, c - l1], -1),
        ],
        1,
    )
    cols = (
        np.cross(m[:, 0], m[:, 1]),
        np.cross(m[:, 0], m[:, 2]),
        np.cross(m[:, 1], m[:, 2]),
    )
    best = np.argmax(np.stack([np.einsum("ni,ni->n", v, v) for v in cols]), axis=0)
    v1 = np.choose(best[:, None], cols)
    v1 = v1 / np.maximum(np.linalg.norm(v1, axis=1, keepdims=True), 1e-300)
    return {
        "linearity": (l1 - l2) / l1,
        "planarity": (l2 - l3) / l1,
        "scattering": l3 / l1,
        "curvature": l3 / (l1 + l2 + l3),
        "verticality": np.abs(v1[:, 2]),
    }


def _sym3_eigenvalues(a, b, c, d, e, f):
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
    return cc(graph, directed=False)[1]
