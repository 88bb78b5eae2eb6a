"""The ground surface of a scan: a levelled plane fitted to the lowest points, plus relief.

Used by the scene stage (``scene.py``) and the plot's stem map. A grid of ``cell_m``
cells keeps each cell's lowest point; a seeded RANSAC finds the plane (slope at most
``max_slope_deg``) that the most cell minima lie on while few lie far below it (the
ground is the lowest surface), a least-squares refit on its inlier cells levels it,
and the relief of each cell is the median residual of the nearest inlier cells (rough
ground, small bumps). A plot, tens of metres wide, asks the ground to follow a
terrain that bends away from the plane, and stray echoes not to vote (``wide``).
A clean, segmented tree has no such surface: its lowest points form the stem foot,
a few square metres at most, so a ground is only declared above ``min_area_m2``.

The planes are found on the scan before the outlier filter (which removes sparse far
ground). A clean tree's best plane stays well under ``min_area_m2``; in a field pair
at least one scan shows a large ground, but a single scan half hidden by a
neighbour may show only a few square metres, and a small plane on shrub bases is
not a ground. So a ground is declared above ``min_area_m2``, or above a smaller area
when the other scan of the pair has one (``expect_ground`` in the scene stage).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from amrst.stages.voxels import column_min

_BELOW_PENALTY = 3.0  # a cell far below a plane costs this many inliers
#: Growing the ground over a bending terrain (``_follow_terrain``): a cell joins
#: from its ground neighbours this near (m), on the plane through this many of them.
_GROW_REACH_M = 1.0
_GROW_NEIGHBOURS = 8


@dataclass(frozen=True, slots=True)
class GroundFit:
    """A fitted ground surface (local coordinates).

    Attributes
    ----------
    found : bool
        True when the plane's inlier cells cover at least the area asked for.
    plane : (3,) float64
        ``z = a x + b y + c`` as (a, b, c).
    area_m2 : float
        Area of the cells whose lowest point lies on the plane.
    n_cells : int
        Occupied cells.
    cell_m : float
    centres : (K, 2) float64
        Centre of every occupied cell.
    relief : (K,) float64
        Height of each cell's ground above the plane (bumps; the plane carries the
        slope, so a sloped cell is not biased towards its downhill edge).
    """

    found: bool
    plane: np.ndarray
    area_m2: float
    n_cells: int
    cell_m: float
    centres: np.ndarray
    relief: np.ndarray

    def height(self, xyz: np.ndarray) -> np.ndarray:
        """(N,) height of points above the ground surface (of their nearest cell).

        Without a ground, the height above the plane through the lowest point.
        """
        a, b, c = self.plane
        if not self.found or len(self.centres) == 0:
            return np.asarray(xyz[:, 2] - (a * xyz[:, 0] + b * xyz[:, 1] + c))
        plane = a * xyz[:, 0] + b * xyz[:, 1] + c
        return np.asarray(xyz[:, 2] - plane - self.relief[self.nearest_cell(xyz)])

    def surface_z(self, xy: np.ndarray) -> np.ndarray:
        """(N,) height of the ground surface at (N, 2) positions (``height``'s zero).

        Without a ground, the plane through the lowest point.
        """
        xy = np.asarray(xy, dtype=float).reshape(-1, 2)
        a, b, c = self.plane
        plane = a * xy[:, 0] + b * xy[:, 1] + c
        if not self.found or len(self.centres) == 0:
            return np.asarray(plane)
        return np.asarray(plane + self.relief[self.nearest_cell(xy)])

    def nearest_cell(self, xyz: np.ndarray) -> np.ndarray:
        """(N,) index of the cell centre nearest each point's x y.

        A point inside an occupied cell is nearer its own centre than any other (at
        most half a cell off in x and in y; every other centre at least that far in
        one of them), so it is looked up in the grid; points in empty cells or within
        a rounding error of a cell edge (where two centres tie) ask a KD-tree.
        """
        from scipy.spatial import cKDTree

        cell = self.cell_m
        cq = np.floor(self.centres / cell)
        lo = cq.min(axis=0)
        span = cq.max(axis=0) - lo + 1
        ci = (cq - lo).astype(np.int64)
        ccode = ci[:, 0] * int(span[1]) + ci[:, 1]
        # x and y one column at a time (numpy's reductions across the columns of an
        # (N, 2) array are slow); the same values as on the (N, 2) arrays.
        inside = np.ones(len(xyz), dtype=bool)
        qi = []
        for d in range(2):
            f = xyz[:, d] / cell
            q = np.floor(f)
            r = f - q
            inside &= np.minimum(r, 1.0 - r) >= 1e-9  # not on a cell edge
            q -= lo[d]
            inside &= (q >= 0) & (q < span[d])
            qi.append(q)
        qx, qy = (q[inside].astype(np.int64) for q in qi)
        qcode = np.zeros(len(xyz), dtype=np.int64)
        qcode[inside] = qx * int(span[1]) + qy
        # The centres come in grid order (fit_ground): ccode is sorted.
        by_code = np.argsort(ccode, kind="stable")
        at = by_code[np.minimum(np.searchsorted(ccode[by_code], qcode), len(ccode) - 1)]
        hit = inside & (ccode[at] == qcode)
        if not hit.all():
            miss = np.flatnonzero(~hit)
            at[miss] = cKDTree(self.centres).query(xyz[miss, :2])[1]
        return at

    @property
    def normal(self) -> np.ndarray:
        """(3,) unit upward normal of the plane."""
        a, b, _ = self.plane
        n = np.array([-a, -b, 1.0])
        return np.asarray(n / np.linalg.norm(n))

    @property
    def tilt_deg(self) -> float:
        """Angle between the plane's normal and the scan's z axis (deg)."""
        return float(np.degrees(np.arccos(np.clip(self.normal[2], -1, 1))))


def fit_ground(
    xyz: np.ndarray,
    *,
    cell_m: float,
    tol_m: float,
    max_slope_deg: float,
    min_area_m2: float,
    iterations: int,
    seed: int,
    wide: bool = False,
) -> GroundFit:
    """Fit the ground surface under a scan.

    Parameters
    ----------
    xyz : (N, 3) float64
    cell_m : float
        Grid cell (m).
    tol_m : float
        A cell minimum within this of the plane is an inlier (m).
    max_slope_deg : float
        Steepest plane considered.
    min_area_m2 : float
        Inlier area needed to call it a ground.
    iterations : int
        RANSAC draws (seeded).
    seed : int
    wide : bool
        A ground tens of metres wide (a plot). Only the cells whose lowest point
        another point of the cell supports (:func:`_supported`) vote for the plane:
        stray echoes below the ground, or far off it, one a cell over the scan's
        reach, would outvote it. The plane is refitted to every cell, and the ground
        then grows from its cells over a terrain that bends away from it
        (:func:`_follow_terrain`): no plot that wide is a plane.

    Returns
    -------
    GroundFit
        ``found`` False (and heights measured from the lowest point) when no plane
        covers ``min_area_m2``.
    """
    n = len(xyz)
    lowest = np.array([0.0, 0.0, float(xyz[:, 2].min()) if n else 0.0])
    none = np.zeros((0, 2))
    if n < 3:
        return GroundFit(False, lowest, 0.0, 0, cell_m, none, np.zeros(0))
    first = _lowest_per_cell(xyz, cell_m)  # one per occupied cell
    mins = xyz[first, 2]
    cxy = (np.floor(xyz[first, :2] / cell_m) + 0.5) * cell_m
    if len(first) < 3:
        return GroundFit(False, lowest, 0.0, len(first), cell_m, none, np.zeros(0))
    # The plane is fitted through the lowest points where they are (not the cell
    # centres): on a slope a cell's lowest point sits at its downhill edge.
    A = np.column_stack([xyz[first, :2], np.ones(len(first))])
    slope = np.tan(np.radians(max_slope_deg))
    # A cell's points may differ by tol_m plus what the steepest ground climbs in it.
    votes = _supported(xyz, first, cell_m, tol_m + cell_m * slope) if wide else None
    coef = _ransac_plane(A, mins, tol_m, slope, iterations, seed, votes=votes)
    for _ in range(3):  # refit on the inliers: the levelled plane
        inl = np.abs(mins - A @ coef) < tol_m
        if inl.sum() < 3:
            break
        coef = np.linalg.lstsq(A[inl], mins[inl], rcond=None)[0]
    resid = mins - A @ coef
    inl = np.abs(resid) < tol_m
    if votes is not None:  # a wide ground
        inl = _follow_terrain(A[:, :2], resid, inl, tol_m, votes)
    area = float(inl.sum() * cell_m**2)
    if area < min_area_m2 or inl.sum() < 3:
        return GroundFit(False, lowest, area, len(first), cell_m, none, np.zeros(0))
    # Relief: each cell takes the median residual of its nearest inlier cells, so
    # bumps follow while a cell with only crown points in it keeps the ground below.
    from scipy.spatial import cKDTree

    at_centre = resid[inl]
    if wide:
        # Where the terrain bends away from the plane, a cell's lowest point lies at
        # its downhill edge, up to a decimetre below its centre: the local plane
        # through the ground around it carries it to the centre.
        k = int(min(_GROW_NEIGHBOURS, inl.sum()))
        on = A[inl, :2]
        nn = cKDTree(on).query(on, k=k)[1].reshape(len(on), k)
        grade = _local_plane(on[nn] - on[:, None], at_centre[nn])[1]
        at_centre = at_centre + np.sum(grade * (cxy[inl] - on), axis=1)
    k = int(min(4, inl.sum()))
    nn = cKDTree(cxy[inl]).query(cxy, k=k)[1].reshape(len(first), k)
    relief = np.median(at_centre[nn], axis=1)
    relief[inl] = at_centre
    return GroundFit(True, coef, area, len(first), cell_m, cxy, relief)


def _follow_terrain(
    xy: np.ndarray,
    resid: np.ndarray,
    ground: np.ndarray,
    tol_m: float,
    eligible: np.ndarray,
) -> np.ndarray:
    """Grow the ground cells outwards from ``ground`` over a bending terrain.

    ``xy``: each cell's lowest point, ``resid`` its height above the plot's plane.

    Each round, a cell next to the ground (its nearest ground cell within
    ``_GROW_REACH_M``) joins it when its lowest point lies within ``tol_m`` of the
    plane through its ``_GROW_NEIGHBOURS`` nearest ground cells: the ground may bend
    away from the plot's plane by metres, but not between neighbouring cells, while a
    shrub or a log stands off the ground beside it. ``eligible``: the cells that may
    join (a stray echo's may not). Stops when a round adds no cell.

    Returns
    -------
    (K,) bool
        The ground cells, ``ground`` among them.
    """
    from scipy.spatial import cKDTree

    ground = ground.copy()
    open_ = ~ground & eligible
    while open_.any() and ground.sum() >= _GROW_NEIGHBOURS:
        on = np.flatnonzero(ground)
        dist, nn = cKDTree(xy[on]).query(xy[open_], k=_GROW_NEIGHBOURS)
        near = dist[:, 0] <= _GROW_REACH_M
        cand = np.flatnonzero(open_)[near]
        nbr = on[nn[near]]  # (M, k) ground cells around each candidate
        level = _local_plane(xy[nbr] - xy[cand, None], resid[nbr])[0]
        join = cand[np.abs(resid[cand] - level) < tol_m]
        if not len(join):
            break
        ground[join] = True
        open_[join] = False
    return ground


def _local_plane(dxy: np.ndarray, z: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Fit a plane to each row's (k,) ``z`` at (k, 2) ``dxy``: (M,) level at 0, (M, 2) slope.

    A little ridge on the slopes keeps a row whose cells lie on a line from tilting
    its plane at will (the level then tends to their mean).
    """
    X = np.concatenate([np.ones((*dxy.shape[:2], 1)), dxy], axis=2)
    XtX = np.einsum("mki,mkj->mij", X, X) + np.diag([0.0, 1e-2, 1e-2])
    Xtz = np.einsum("mki,mk->mi", X, z)
    coef = np.linalg.solve(XtX, Xtz[..., None])[..., 0]
    return np.asarray(coef[:, 0]), np.asarray(coef[:, 1:])


def _lowest_per_cell(xyz: np.ndarray, cell_m: float) -> np.ndarray:
    """Index of the lowest point of each occupied cell, cells in grid order.

    Ties go to the lowest index (what a stable sort by cell, then height, keeps
    first). An unstable sort groups the points by cell (SIMD sorts are faster than a
    stable one); the minimum height of a run does not depend on the order inside
    it, and the lowest index among a cell's lowest points is taken over the few
    points at that height, in index order.
    """
    ij = np.floor(xyz[:, :2] / cell_m).astype(np.int64)
    ij -= column_min(ij)
    code = ij[:, 0] * (int(ij[:, 1].max()) + 1) + ij[:, 1]
    order = np.argsort(code)
    sc = code[order]
    start = np.flatnonzero(np.r_[True, sc[1:] != sc[:-1]])
    z = xyz[:, 2]
    zs = z[order]
    low = np.minimum.reduceat(zs, start)
    run = np.repeat(np.arange(len(start)), np.diff(np.r_[start, len(order)]))
    hit = zs == low[run]  # every point at its cell's lowest height
    first = np.full(len(start), len(z), dtype=np.int64)
    np.minimum.at(first, run[hit], order[hit])
    return first


def _supported(
    xyz: np.ndarray, first: np.ndarray, cell_m: float, gap_m: float
) -> np.ndarray:
    """Mark the cells whose lowest point another point of the cell supports.

    ``first``: each occupied cell's lowest point, cells in grid order (as
    :func:`_lowest_per_cell` gives them). A cell's lowest point is supported when
    another point of the cell lies within ``gap_m`` above it; a cell of one point is
    not. A lone point below the ground (multipath echoes, noise a filter missed)
    would otherwise be its cell's ground, and many of them, spread over a scan's
    reach, the lowest surface the plane is drawn to.
    """
    rest = np.ones(len(xyz), dtype=bool)
    rest[first] = False
    others = np.flatnonzero(rest)
    if len(others) == 0:
        return np.zeros(len(first), dtype=bool)
    second = others[_lowest_per_cell(xyz[others], cell_m)]
    ij = np.floor(xyz[:, :2] / cell_m).astype(np.int64)
    ij -= column_min(ij)
    span = int(ij[:, 1].max()) + 1

    def code(rows: np.ndarray) -> np.ndarray:
        return np.asarray(ij[rows, 0] * span + ij[rows, 1])

    # Both lists are in grid order: each cell's next lowest point is found by search.
    at = np.minimum(np.searchsorted(code(second), code(first)), len(second) - 1)
    nxt = second[at]
    return np.asarray(
        (code(nxt) == code(first)) & (xyz[nxt, 2] - xyz[first, 2] <= gap_m)
    )


def _ransac_plane(
    A: np.ndarray,
    z: np.ndarray,
    tol: float,
    max_slope: float,
    iterations: int,
    seed: int,
    *,
    votes: np.ndarray | None = None,
) -> np.ndarray:
    """Plane (a, b, c) with the most cell minima on it and the fewest far below it.

    ``votes``: the cells that count (all when None); the draws are made from them.

    The draws are solved and scored in blocks (one batched solve, one matrix product
    per block), the first best draw wins as in a loop over them.
    """
    rng = np.random.default_rng(seed)
    best = np.array([0.0, 0.0, float(np.min(z))])
    if votes is not None:
        A, z = A[votes], z[votes]
        if len(z) < 3:
            return best
    draws = rng.integers(0, len(z), size=(iterations, 3))
    coefs = _solve_draws(A[draws], z[draws])
    usable = np.isfinite(coefs).all(axis=1)
    usable[usable] = np.hypot(coefs[usable, 0], coefs[usable, 1]) <= max_slope
    cand = np.flatnonzero(usable)
    if len(cand) == 0:
        return best
    scores = np.empty(len(cand))
    block = max(1, 2_000_000 // max(len(z), 1))
    for s in range(0, len(cand), block):
        c = coefs[cand[s : s + block]]
        r = z[:, None] - A @ c.T
        scores[s : s + block] = np.sum(np.abs(r) < tol, axis=0) - _BELOW_PENALTY * (
            np.sum(r < -2 * tol, axis=0)
        )
    return np.asarray(coefs[cand[int(np.argmax(scores))]])


def _solve_draws(M: np.ndarray, b: np.ndarray) -> np.ndarray:
    """(I, 3) solutions of the (I, 3, 3) systems; NaN rows where one is singular.

    np.linalg.solve refuses a whole batch for one singular system (a draw that
    repeats a cell often is; not every one, as LAPACK scales by a reciprocal pivot).
    Its kernel, called with the invalid-value flag ignored, solves each system with
    the same LAPACK call and leaves NaN where one is singular, in one call. Without
    that kernel (another numpy) the batch is halved down to each singular system.
    """
    try:
        from numpy.linalg import _umath_linalg

        kernel = _umath_linalg.solve
    except (ImportError, AttributeError):  # pragma: no cover - numpy without it
        return _halve_draws(M, b)
    with np.errstate(invalid="ignore", over="ignore", divide="ignore", under="ignore"):
        x = kernel(M, b[..., None], signature="dd->d")
    return np.asarray(x[..., 0])


def _halve_draws(M: np.ndarray, b: np.ndarray) -> np.ndarray:
    """:func:`_solve_draws` through np.linalg.solve, halving a batch it refuses."""
    try:
        return np.asarray(np.linalg.solve(M, b[..., None])[..., 0])
    except np.linalg.LinAlgError:
        if len(M) == 1:
            return np.full(b.shape, np.nan)
        h = len(M) // 2
        return np.concatenate([_halve_draws(M[:h], b[:h]), _halve_draws(M[h:], b[h:])])
