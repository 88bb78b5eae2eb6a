"""The virtual scanner's optics: which points a tripod scanner at the origin records.

Every point is a small disc (``footprints``) that covers the beam-grid cells within
its angular radius; each cell keeps its nearest point (``visible_points``), so points
hidden behind nearer ones are dropped and density falls with range. Used by
``amrst.simulate``.
"""

from __future__ import annotations

from typing import cast

import numpy as np

# A point's footprint covers at most (2 * _MAX_HALF_BINS + 1)^2 grid cells; this bounds
# memory for points very close to the scanner or near the zenith.
_MAX_HALF_BINS = 12
# The grid is coarsened until a typical disc spans this many cells in radius.
_CELLS_PER_RADIUS = 4.0


def footprints(xyz: np.ndarray, k: int = 4) -> np.ndarray:
    """Per-point disc radius: the distance to the k-th nearest neighbour (m).

    Capped at three times the median so that isolated points do not hide whole regions.

    Parameters
    ----------
    xyz : (N, 3) float64
    k : int

    Returns
    -------
    (N,) float64
    """
    from scipy.spatial import cKDTree

    d = cKDTree(xyz).query(xyz, k=k + 1)[0][:, -1]
    return cast("np.ndarray", np.minimum(d, 3.0 * float(np.median(d))))


def visible_points(
    xyz: np.ndarray, res_deg: float, footprint_m: float | np.ndarray
) -> np.ndarray:
    """Return indices of the points a scanner at the origin records (nearest per beam).

    Parameters
    ----------
    xyz : (N, 3) float64
        Points in the scanner frame.
    res_deg : float
        Angular step of the beam grid in azimuth and elevation (deg).
    footprint_m : float or (N,) float64
        Radius of the disc each point stands for (m).

    Returns
    -------
    (K,) int64
        Sorted indices of the points that are nearest in at least one grid cell.
    """
    r = np.linalg.norm(xyz, axis=1)
    idx = np.flatnonzero(r > 0.05)
    p, r = xyz[idx], r[idx]
    radius = np.broadcast_to(np.asarray(footprint_m, dtype=float), (len(xyz),))[idx]
    # Beams finer than a quarter of the typical disc change nothing but the cost: every
    # visible point already wins cells; so the grid is only as fine as that.
    typical = float(np.median(radius / r)) if len(r) else 0.0
    res = max(np.radians(res_deg), typical / _CELLS_PER_RADIUS)
    n_az = int(np.ceil(2 * np.pi / res))
    el = np.arcsin(np.clip(p[:, 2] / r, -1.0, 1.0))
    fa = (np.arctan2(p[:, 1], p[:, 0]) + np.pi) / res  # fractional cell coordinates
    fe = (el + np.pi / 2) / res
    ke = np.maximum(radius / r / res, 1e-9)  # angular radius in cells
    ka = ke / np.maximum(np.cos(el), 1e-3)  # an azimuth step shrinks towards the zenith
    na = np.minimum(np.ceil(ka), _MAX_HALF_BINS).astype(np.int64)
    ne = np.minimum(np.ceil(ke), _MAX_HALF_BINS).astype(np.int64)
    # Expand every point into its (2na+1) x (2ne+1) block of candidate cells.
    width = 2 * na + 1
    counts = width * (2 * ne + 1)
    pid = np.repeat(np.arange(len(p)), counts)
    k = np.arange(counts.sum()) - np.repeat(np.cumsum(counts) - counts, counts)
    da = k % width[pid] - na[pid]
    de = k // width[pid] - ne[pid]
    ia = np.floor(fa).astype(np.int64)[pid] + da
    ie = np.floor(fe).astype(np.int64)[pid] + de
    # Keep the cells whose centre lies inside the point's disc, and always its own cell.
    u = (ia + 0.5 - fa[pid]) / ka[pid]
    v = (ie + 0.5 - fe[pid]) / ke[pid]
    keep = (u * u + v * v <= 1.0) | ((da == 0) & (de == 0))
    pid, ia, ie = pid[keep], ia[keep], ie[keep]
    cell = (ie * n_az + np.mod(ia, n_az)).astype(np.int64)
    # One sort on (cell, range in 0.1 mm): each cell's first entry is its nearest point.
    r_q = np.minimum(np.round(r[pid] * 1e4), 2**24 - 1).astype(np.int64)
    order = np.argsort(cell * 2**24 + r_q, kind="stable")
    cell_sorted = cell[order]
    first = np.ones(len(order), dtype=bool)
    first[1:] = cell_sorted[1:] != cell_sorted[:-1]
    return cast("np.ndarray", idx[np.unique(pid[order[first]])])
