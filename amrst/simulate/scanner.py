"""The virtual scanner's optics: which points a tripod scanner at the origin records.

Every point is a small disc (``footprints``) that covers the beam-grid cells within
its angular radius; each cell keeps its nearest point (``visible_points``), so points
hidden behind nearer ones are dropped and density falls with range. Used by
``amrst.simulate``.
"""

from __future__ import annotations

import itertools
from typing import cast

import numpy as np

from amrst.stages.voxels import sorted_unique

# A point's footprint covers at most (2 * _MAX_HALF_BINS + 1)^2 grid cells; this bounds
# memory for points very close to the scanner or near the zenith.
_MAX_HALF_BINS = 12
# The grid is coarsened until a typical disc spans this many cells in radius.
_CELLS_PER_RADIUS = 4.0
# Candidate cells expanded at once: bounds the temporaries (about 100 bytes a cell).
_CHUNK_CELLS = 2_000_000


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
    counts = (2 * na + 1) * (2 * ne + 1)
    # Points are expanded a chunk at a time and each chunk reduced to its nearest
    # point per cell, then the chunks' winners to the scan's: memory stays a chunk's,
    # and ties still go to the lower point index, as in one pass over all points.
    r_q = np.minimum(np.round(r * 1e4), 2**24 - 1).astype(np.int64)  # 0.1 mm
    grid = (
        fa,
        fe,
        ka,
        ke,
        na,
        ne,
        np.floor(fa).astype(np.int64),
        np.floor(fe).astype(np.int64),
    )
    winners = [
        _nearest_per_cell(np.arange(a, b), counts[a:b], grid, r_q, n_az)
        for a, b in _chunks(counts)
    ]
    if not winners:
        return idx[:0]
    cell = np.concatenate([w[0] for w in winners])
    key = np.concatenate([w[1] for w in winners])
    pid = np.concatenate([w[2] for w in winners])
    best = _first_per_cell(cell, key)
    return cast("np.ndarray", idx[sorted_unique(pid[best])])


def _chunks(counts: np.ndarray) -> list[tuple[int, int]]:
    """Split the points into runs whose cells add up to about ``_CHUNK_CELLS``."""
    ends = np.searchsorted(
        np.cumsum(counts),
        np.arange(_CHUNK_CELLS, int(counts.sum()) + _CHUNK_CELLS, _CHUNK_CELLS),
        side="right",
    )
    bounds = np.unique(np.r_[0, np.minimum(ends, len(counts)), len(counts)])
    return [(int(a), int(b)) for a, b in itertools.pairwise(bounds) if b > a]


def _nearest_per_cell(
    pid: np.ndarray,
    counts: np.ndarray,
    grid: tuple[np.ndarray, ...],
    r_q: np.ndarray,
    n_az: int,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Expand the points ``pid`` into their cells; return each cell's nearest point.

    Returns (cell, range key, point index) of the winners, one per cell.
    """
    fa, fe, ka, ke, na, ne, ia0, ie0 = grid
    # Expand every point into its (2na+1) x (2ne+1) block of candidate cells.
    width = (2 * na + 1)[pid]
    own = np.repeat(pid, counts)
    k = np.arange(counts.sum()) - np.repeat(np.cumsum(counts) - counts, counts)
    w = np.repeat(width, counts)
    da = k % w - na[own]
    de = k // w - ne[own]
    ia = ia0[own] + da
    ie = ie0[own] + de
    # Keep the cells whose centre lies inside the point's disc, and always its own cell.
    u = (ia + 0.5 - fa[own]) / ka[own]
    v = (ie + 0.5 - fe[own]) / ke[own]
    keep = (u * u + v * v <= 1.0) | ((da == 0) & (de == 0))
    own, ia, ie = own[keep], ia[keep], ie[keep]
    cell = (ie * n_az + np.mod(ia, n_az)).astype(np.int64)
    key = r_q[own]
    best = _first_per_cell(cell, key)
    return cell[best], key[best], own[best]


def _first_per_cell(cell: np.ndarray, key: np.ndarray) -> np.ndarray:
    """Return the index of each cell's smallest key; of equal keys, the first given."""
    order = np.argsort(cell * 2**24 + key, kind="stable")
    sorted_cells = cell[order]
    first = np.ones(len(order), dtype=bool)
    first[1:] = sorted_cells[1:] != sorted_cells[:-1]
    return cast("np.ndarray", order[first])
