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
    cov = np.einsum("nki,nkj->nij", nb, nb) / k
    w, v = np.linalg.eigh(cov)  # ascending
    w = np.clip(w, 1e-12, None)
    l3, l2, l1 = w[:, 0], w[:, 1], w[:, 2]
    return {
        "linearity": (l1 - l2) / l1,
        "planarity": (l2 - l3) / l1,
        "scattering": l3 / l1,
        "curvature": l3 / (l1 + l2 + l3),
        "verticality": np.abs(v[:, 2, 2]),
    }


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
