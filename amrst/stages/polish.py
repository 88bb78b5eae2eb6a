"""Short batched ICP and the voxel occupancy test, shared by verification and the trunk search.

``polish`` runs a point-to-point ICP from many starts at once (one KD-tree query per
iteration serves them all); ``Occupancy`` scores where sampled source points land on
a dilated voxel grid of the target.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, cast

import numpy as np

if TYPE_CHECKING:
    from collections.abc import Callable

    from scipy.spatial import cKDTree

POLISH_ITERATIONS = 15
# A polish iteration that moves less than this (m, rad) ends its scale: the fine
# stage follows, so the polish only has to bring a pose within the 4 cm tight score.
POLISH_STOP_M = 5e-4
POLISH_STOP_RAD = 1e-4


class Occupancy:
    """Dilated voxel occupancy of the target, as sorted int64 codes."""

    def __init__(self, xyz: np.ndarray, voxel: float) -> None:
        self.voxel = voxel
        keys = np.floor(xyz / voxel).astype(np.int64)
        keys = keys[np.unique(self._code(keys), return_index=True)[1]]
        offs = (
            np.array(np.meshgrid([-1, 0, 1], [-1, 0, 1], [-1, 0, 1])).reshape(3, -1).T
        )
        self.codes = np.unique(
            self._code((keys[:, None, :] + offs[None]).reshape(-1, 3))
        )

    @staticmethod
    def _code(k: np.ndarray) -> np.ndarray:
        k = k + (1 << 20)
        return cast("np.ndarray", (k[..., 0] << 42) | (k[..., 1] << 21) | k[..., 2])

    def fraction_many(self, pts: np.ndarray) -> np.ndarray:
        """(G,) occupied fraction of each of G point sets given as (G, n, 3)."""
        code = self._code(np.floor(pts / self.voxel).astype(np.int64))
        pos = np.minimum(np.searchsorted(self.codes, code), len(self.codes) - 1)
        return cast("np.ndarray", np.mean(self.codes[pos] == code, axis=1))


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
    tree: cKDTree,
    Ts: np.ndarray,
    max_dist: float,
    fit: Callable[[np.ndarray, np.ndarray, np.ndarray], np.ndarray] = rigid_steps,
    iterations: int = POLISH_ITERATIONS,
) -> np.ndarray:
    """Run a short point-to-point ICP from B starts at once.

    Each iteration takes the closed-form ``fit`` step (Kabsch by default), at max_dist
    and then a third of it (what Open3D's point-to-point ICP does; importing Open3D
    would cost a second per command).

    One KD-tree query per iteration serves every start still moving; a start stops a
    scale when its step is below POLISH_STOP_M / POLISH_STOP_RAD, and stops for good
    when fewer than 6 of its points find a partner. ``tree`` is a cKDTree on ``tgt``;
    ``Ts`` (B, 4, 4); returns the polished (B, 4, 4).
    """
    Ts = np.array(Ts, dtype=float).reshape(-1, 4, 4)
    alive = np.ones(len(Ts), dtype=bool)
    for dist in (max_dist, max_dist / 3):
        moving = alive.copy()
        for _ in range(iterations):
            idx = np.flatnonzero(moving)
            if not len(idx):
                break
            T = Ts[idx]
            moved = np.einsum("bij,nj->bni", T[:, :3, :3], src) + T[:, None, :3, 3]
            d, j = tree.query(moved.reshape(-1, 3), distance_upper_bound=dist)
            ok = (d < dist).reshape(len(idx), -1)
            enough = ok.sum(axis=1) >= 6
            alive[idx[~enough]] = moving[idx[~enough]] = False
            idx, moved, ok = idx[enough], moved[enough], ok[enough]
            if not len(idx):
                break
            partner = tgt[np.minimum(j, len(tgt) - 1)].reshape(-1, len(src), 3)
            step = fit(moved, partner[enough], ok.astype(float))
            Ts[idx] = step @ Ts[idx]
            still = (np.linalg.norm(step[:, :3, 3], axis=1) >= POLISH_STOP_M) | (
                np.trace(step[:, :3, :3], axis1=1, axis2=2) <= 3 - POLISH_STOP_RAD**2
            )
            moving[idx[~still]] = False
    return Ts
