"""Small geometric solvers shared by the stages and the app's manual alignment."""

from __future__ import annotations

import functools
import math

import numpy as np


def yaw_rotation(yaw: float) -> np.ndarray:
    """(3, 3) the rotation by ``yaw`` radians about the vertical (z) axis."""
    c, s = np.cos(yaw), np.sin(yaw)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def rotvec_matrix(w: np.ndarray) -> np.ndarray:
    """(3, 3) the rotation by the vector ``w`` (axis times angle in radians).

    The arithmetic of scipy's ``Rotation.from_rotvec(w).as_matrix()`` (quaternion
    with its small-angle series, then its quaternion-to-matrix formula), bit for bit
    (tested), on Python floats: far cheaper than building a ``Rotation``, which counts
    in LM-ICP's steps.
    """
    x, y, z = float(w[0]), float(w[1]), float(w[2])
    angle = math.sqrt(x * x + y * y + z * z)
    if angle <= 1e-3:
        a2 = angle * angle
        scale = 0.5 - a2 / 48 + a2 * a2 / 3840
    else:
        scale = math.sin(angle / 2) / angle
    qx, qy, qz, qw = x * scale, y * scale, z * scale, math.cos(angle / 2)
    x2, y2, z2, w2 = qx * qx, qy * qy, qz * qz, qw * qw
    xy, zw, xz, yw, yz, xw = qx * qy, qz * qw, qx * qz, qy * qw, qy * qz, qx * qw
    return np.array(
        [
            [x2 - y2 - z2 + w2, 2 * (xy - zw), 2 * (xz + yw)],
            [2 * (xy + zw), -x2 + y2 - z2 + w2, 2 * (yz - xw)],
            [2 * (xz - yw), 2 * (yz + xw), -x2 - y2 + z2 + w2],
        ]
    )


def kabsch(src: np.ndarray, dst: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Batched least-squares rigid fit dst ≈ R src + t.

    Parameters
    ----------
    src, dst : (B, K, 3) float64

    Returns
    -------
    (B, 4, 4) transforms and (B,) RMS residuals (m).
    """
    cs, cd = src.mean(axis=1, keepdims=True), dst.mean(axis=1, keepdims=True)
    h = np.einsum("bki,bkj->bij", src - cs, dst - cd)
    u, _, vt = np.linalg.svd(h)
    d = np.sign(np.linalg.det(np.einsum("bij,bjk->bik", u, vt)))
    fix = np.ones((len(src), 3))
    fix[:, 2] = d
    R = np.einsum("bji,bj,bkj->bik", vt, fix, u)  # V diag(1,1,d) U^T
    t = cd[:, 0] - np.einsum("bij,bj->bi", R, cs[:, 0])
    out = np.tile(np.eye(4), (len(src), 1, 1))
    out[:, :3, :3], out[:, :3, 3] = R, t
    moved = np.einsum("bij,bkj->bki", R, src) + t[:, None]
    res = np.sqrt(np.mean(np.sum((moved - dst) ** 2, axis=2), axis=1))
    return out, res


def kasa_circle(xy: np.ndarray, about: np.ndarray) -> tuple[np.ndarray, float]:
    """Fit a circle to (N, 2) points by Kasa's algebraic least squares.

    x² + y² = 2ax + 2by + c is linear in (a, b, c); the points are taken relative to
    ``about`` (their median or mean), which keeps the system well conditioned.
    Returns the centre and the squared radius; that is NaN for points on a line or
    fewer than three, and may be ≤ 0 for points no circle fits.
    """
    x, y = xy[:, 0] - about[0], xy[:, 1] - about[1]
    A = np.column_stack([2 * x, 2 * y, np.ones(len(x))])
    scale = max(float(np.abs(A).max(initial=0.0)), 1e-12)
    if len(x) < 3 or np.linalg.matrix_rank(A, tol=1e-9 * scale) < 3:
        return np.asarray(about, float)[:2].copy(), float("nan")
    a, b, c = np.linalg.lstsq(A, x * x + y * y, rcond=None)[0]
    return np.array([about[0] + a, about[1] + b]), float(c + a * a + b * b)


@functools.lru_cache(maxsize=4)
def combinations4(n: int) -> np.ndarray:
    """(C(n,4), 4) int64 all index quadruples i<j<k<l, in lexicographic order.

    Cached (read-only): both scans usually have the same number of key points.
    """
    pairs = np.column_stack(np.triu_indices(n, 1))  # (i, j), i < j
    out = []
    for i, j in pairs:  # at most C(n,2) small blocks, each vectorised
        if j >= n - 2:
            continue
        kl = pairs[pairs[:, 0] > j]
        out.append(np.column_stack([np.full(len(kl), i), np.full(len(kl), j), kl]))
    quads = np.concatenate(out) if out else np.zeros((0, 4), dtype=np.int64)
    quads.setflags(write=False)
    return quads
