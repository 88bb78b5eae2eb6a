"""Short batched ICP and the voxel occupancy test, shared by verification and the trunk search.

``polish`` runs a point-to-point ICP from many starts at once (one KD-tree query per
iteration serves them all); ``Occupancy`` scores where sampled source points land on
a dilated voxel grid of the target.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, cast

import numpy as np

from amrst.stages.nearest_cache import NearestCache
from amrst.stages.voxels import sorted_unique

if TYPE_CHECKING:
    from collections.abc import Callable

    from amrst.stages.nearest_cache import NearestQuery

POLISH_ITERATIONS = 15
# A polish iteration that moves less than this (m, rad) ends its scale: the fine
# stage follows, so the polish only has to bring a pose within the 4 cm tight score.
POLISH_STOP_M = 5e-4
POLISH_STOP_RAD = 1e-4


class Occupancy:
    """Dilated voxel occupancy of the target: which voxels lie on or next to a point.

    A dense boolean grid over the target's bounding box (two empty layers around it,
    so a query outside reads an empty border cell) when it has at most ``MAX_CELLS``
    cells: built faster than the sorted codes (three sorts of a growing code list)
    and read with one lookup instead of a binary search. Larger boxes keep
    the sorted int64 codes. Both answer the same.
    """

    MAX_CELLS = 1 << 25  # 32 MB of bool

    def __init__(self, xyz: np.ndarray, voxel: float) -> None:
        self.voxel = voxel
        keys = np.floor(xyz / voxel).astype(np.int64).reshape(-1, 3)
        self._grid: np.ndarray | None = None
        self._codes: np.ndarray | None = None
        if len(keys) == 0:
            self._codes = np.zeros(0, np.int64)
            return
        self._lo = keys.min(axis=0) - 2
        self._shape = keys.max(axis=0) - self._lo + 3
        sx, sy, sz = (int(s) for s in self._shape)  # Python ints: no overflow
        if min(sx, sy, sz) > 0 and sx * sy * sz <= self.MAX_CELLS:
            self._grid = self._dense(keys - self._lo)
        else:
            self._codes = self._sparse(keys)

    def _dense(self, keys: np.ndarray) -> np.ndarray:
        grid = np.zeros(tuple(int(s) for s in self._shape), dtype=bool)
        grid[keys[:, 0], keys[:, 1], keys[:, 2]] = True
        for axis in range(3):  # dilate by one voxel along each axis
            out = grid.copy()
            hi = [slice(None)] * 3
            lo = [slice(None)] * 3
            hi[axis], lo[axis] = slice(1, None), slice(None, -1)
            out[tuple(hi)] |= grid[tuple(lo)]
            out[tuple(lo)] |= grid[tuple(hi)]
            grid = out
        return grid

    @classmethod
    def _sparse(cls, keys: np.ndarray) -> np.ndarray:
        codes = sorted_unique(cls._code(keys))
        # Dilate by one voxel along z, then y, then x: the same 27-neighbourhood as
        # adding all 27 offsets at once, with three smaller sorts instead of one of
        # 27 times the occupied voxels.
        for shift in (1, 1 << 21, 1 << 42):
            codes = sorted_unique(np.concatenate([codes - shift, codes, codes + shift]))
        return codes

    @property
    def codes(self) -> np.ndarray:
        """Sorted int64 codes (``_code``) of the occupied, dilated voxels."""
        if self._codes is not None:
            return self._codes
        assert self._grid is not None
        cells = np.column_stack(np.nonzero(self._grid)) + self._lo
        return np.sort(self._code(cells))

    @staticmethod
    def _code(k: np.ndarray) -> np.ndarray:
        k = k + (1 << 20)
        return cast("np.ndarray", (k[..., 0] << 42) | (k[..., 1] << 21) | k[..., 2])

    def hits_many(self, pts: np.ndarray) -> np.ndarray:
        """(G, n) bool: which points of G (G, n, 3) point sets land on or near a voxel."""
        keys = np.floor(pts / self.voxel).astype(np.int64)
        if self._grid is not None:
            keys -= self._lo
            np.clip(keys, 0, self._shape - 1, out=keys)  # outside: an empty border
            sy, sz = int(self._shape[1]), int(self._shape[2])
            flat = (keys[..., 0] * sy + keys[..., 1]) * sz + keys[..., 2]
            return cast("np.ndarray", self._grid.ravel()[flat])
        code = self._code(keys)
        assert self._codes is not None
        if len(self._codes) == 0:
            return np.zeros(code.shape, dtype=bool)
        pos = np.minimum(np.searchsorted(self._codes, code), len(self._codes) - 1)
        return cast("np.ndarray", self._codes[pos] == code)

    def fraction_many(self, pts: np.ndarray) -> np.ndarray:
        """(G,) occupied fraction of each of G point sets given as (G, n, 3)."""
        return cast("np.ndarray", np.mean(self.hits_many(pts), axis=1))


def transform_many(Ts: np.ndarray, pts: np.ndarray) -> np.ndarray:
    """Move (n, 3) points by each of B (B, 4, 4) transforms; (B, n, 3).

    The same values bit for bit as ``np.einsum("bij,nj->bni", R, pts) + t`` (whose
    inner sum runs x, z, y), and faster: that einsum has no fast path here.
    """
    R = Ts[:, :3, :3]
    x, y, z = pts[:, 0], pts[:, 1], pts[:, 2]
    return np.stack(
        [
            (R[:, i, 0, None] * x + R[:, i, 2, None] * z)
            + R[:, i, 1, None] * y
            + Ts[:, i, 3, None]
            for i in range(3)
        ],
        axis=-1,
    )


def weighted_centres(
    p: np.ndarray, q: np.ndarray, w: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Centroids of (B, n, 3) point sets under (B, n) 0/1 weights, and the offsets."""
    sw = w.sum(axis=1)[:, None]
    pc = np.matmul(w[:, None, :], p)[:, 0] / sw
    qc = np.matmul(w[:, None, :], q)[:, 0] / sw
    return pc, qc, p - pc[:, None], q - qc[:, None]


def rigid_steps(p: np.ndarray, q: np.ndarray, w: np.ndarray) -> np.ndarray:
    """Fit q ≈ R p + t by least squares (Kabsch) for B point sets at once; (B, 4, 4).

    Each set is fitted on its points with weight 1.
    """
    pc, qc, a, b = weighted_centres(p, q, w)
    u, _, vt = np.linalg.svd(np.matmul((a * w[..., None]).transpose(0, 2, 1), b))
    R = np.einsum("bji,bkj->bik", vt, u)  # V Uᵀ
    flip = np.linalg.det(R) < 0
    vt[flip, 2] *= -1
    R[flip] = np.einsum("bji,bkj->bik", vt[flip], u[flip])
    out = np.tile(np.eye(4), (len(p), 1, 1))
    out[:, :3, :3] = R
    out[:, :3, 3] = qc - np.einsum("bij,bj->bi", R, pc)
    return out


def polish(
    src: np.ndarray,
    tgt: np.ndarray,
    tree: NearestQuery,
    Ts: np.ndarray,
    max_dist: float,
    *,
    fit: Callable[[np.ndarray, np.ndarray, np.ndarray], np.ndarray] = rigid_steps,
    iterations: int = POLISH_ITERATIONS,
) -> np.ndarray:
    """Run a short point-to-point ICP from B starts at once.

    Each iteration takes the closed-form ``fit`` step (Kabsch by default), at max_dist
    and then a third of it (what Open3D's point-to-point ICP does, without importing
    Open3D into every command).

    Every start's points keep their partners in one :class:`NearestCache`: only the
    points that may have found another nearest target point since are queried again
    (the same partners bit for bit, for fewer queries).
    A start stops a scale when its step is below POLISH_STOP_M / POLISH_STOP_RAD, and
    stops for good when fewer than 6 of its points find a partner. ``tree`` is a
    KD-tree on ``tgt`` (``cKDTree`` or ``NearestTree``); ``Ts`` (B, 4, 4); returns the
    polished (B, 4, 4).
    """
    Ts = np.array(Ts, dtype=float).reshape(-1, 4, 4)
    n = len(src)
    alive = np.ones(len(Ts), dtype=bool)
    # Points with no target point within the cache's reach need no query: a dilated
    # voxel grid at least that coarse tells them (exactly: anything closer lies in a
    # neighbouring voxel).
    occ = Occupancy(tgt, 1.05 * 1.5 * max_dist)
    nearest = NearestCache(
        tree, tgt, len(Ts) * n, max_dist, lambda pts: occ.hits_many(pts[None])[0]
    )
    for dist in (max_dist, max_dist / 3):
        nearest.max_dist = dist
        moving = alive.copy()
        for _ in range(iterations):
            idx = np.flatnonzero(moving)
            if not len(idx):
                break
            T = Ts[idx]
            moved = transform_many(T, src)
            rows = (idx[:, None] * n + np.arange(n)).reshape(-1)
            # Every start still moving: all tracked rows in order (no gathers).
            every = len(idx) == len(Ts)
            inside, q = nearest.match(moved.reshape(-1, 3), None if every else rows)
            found = np.zeros(len(rows), dtype=bool)
            found[inside] = True
            ok = found.reshape(len(idx), n)
            enough = ok.sum(axis=1) >= 6
            alive[idx[~enough]] = moving[idx[~enough]] = False
            flat = np.zeros((len(rows), 3))  # partners; zeros (weight 0) for none
            flat[inside] = q
            partner = flat.reshape(len(idx), n, 3)
            idx, moved, ok = idx[enough], moved[enough], ok[enough]
            if not len(idx):
                break
            step = fit(moved, partner[enough], ok.astype(float))
            Ts[idx] = step @ Ts[idx]
            still = (np.linalg.norm(step[:, :3, 3], axis=1) >= POLISH_STOP_M) | (
                np.trace(step[:, :3, :3], axis1=1, axis2=2) <= 3 - POLISH_STOP_RAD**2
            )
            moving[idx[~still]] = False
    return Ts
