"""Point pairs for the Manual dock: the fit with shift locks, the table's rows, and
the world coordinates the pairs file holds. No Qt.

The locks fix components of the world shift at zero (a scanner set up at the same
height, or on the same line): with them the heading is found by a search over the
turn about the vertical, since the closed-form levelled fit frees all three.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from amrst.errors import InvalidInput
from amrst.geometry import yaw_rotation
from amrst.review import manual
from amrst.types import local_transform

if TYPE_CHECKING:
    from amrst.types import Cloud

# Turns tried by the locked fit before it refines the best one (degrees apart).
_YAW_STEP_DEG = 0.25


def fit_locked(
    target_world: np.ndarray, source_world: np.ndarray, locks: tuple[bool, ...]
) -> np.ndarray:
    """Turn about the vertical and shift, the shift's ``locks`` (x, y, z) held at 0.

    Parameters
    ----------
    target_world, source_world : (K, 3) float64
        The pairs in world coordinates, K >= 1 (K >= 2 unless x and y are locked).
    locks : (bool, bool, bool)

    Returns
    -------
    (4, 4) float64
        World ``T_target_source``.

    Raises
    ------
    InvalidInput
        The points leave the turn unknown: with a free horizontal shift, the points
        of a scan with no horizontal spread; with none, points on the vertical
        through the world origin.
    """
    from scipy.optimize import minimize_scalar

    t = np.asarray(target_world, float).reshape(-1, 3)
    s = np.asarray(source_world, float).reshape(-1, 3)
    free = ~np.asarray(locks, bool)
    # The turn is fixed by the points' spread about what the shift leaves free.
    for points, scan in ((s, "source"), (t, "target")):
        about = points[:, :2].mean(axis=0) if free[:2].any() else np.zeros(2)
        if (
            not len(points)
            or np.linalg.norm(points[:, :2] - about, axis=1).max() < 1e-3
        ):
            raise InvalidInput(
                f"The {scan} points are on one vertical line, so the heading is "
                "unknown: pick points that are apart horizontally."
            )

    def shift(yaw: float) -> np.ndarray:
        r = t - s @ yaw_rotation(yaw).T
        return np.where(free, r.mean(axis=0), 0.0)

    def cost(yaw: float) -> float:
        r = t - s @ yaw_rotation(yaw).T - shift(yaw)
        return float(np.sum(r**2))

    yaws = np.deg2rad(np.arange(-180.0, 180.0, _YAW_STEP_DEG))
    best = float(yaws[int(np.argmin([cost(y) for y in yaws]))])
    step = np.deg2rad(_YAW_STEP_DEG)
    yaw = float(
        minimize_scalar(cost, bounds=(best - step, best + step), method="bounded").x
    )
    out = np.eye(4)
    out[:3, :3] = yaw_rotation(yaw)
    out[:3, 3] = shift(yaw)
    return out


def fit_pairs(
    target: Cloud,
    source: Cloud,
    pairs: list[tuple[np.ndarray, np.ndarray]],
    levelled: bool,
    locks: tuple[bool, bool, bool] = (False, False, False),
) -> manual.PairFit:
    """Fit ``pairs`` (local points of each scan) as ``manual.fit_pairs`` does, or,
    with any lock (levelled only), with the world shift's locked parts at 0.

    Raises ``InvalidInput`` when the pairs cannot fix the pose.
    """
    t = np.array([p[0] for p in pairs], float).reshape(-1, 3)
    s = np.array([p[1] for p in pairs], float).reshape(-1, 3)
    if not (levelled and any(locks)):
        return manual.fit_pairs(t, s, levelled)
    T_world = fit_locked(t + target.offset, s + source.offset, locks)
    T = local_transform(T_world, target, source)
    return manual.PairFit(T, manual.pair_residuals(T, t, s), True)


def residual_vectors(T: np.ndarray, pairs: list) -> np.ndarray:
    """(K, 3) moved source point minus its target point, in the target frame (m)."""
    if not pairs:
        return np.zeros((0, 3))
    t = np.array([p[0] for p in pairs], float)
    s = np.array([p[1] for p in pairs], float)
    return np.asarray(s @ T[:3, :3].T + T[:3, 3] - t)


def world_pairs(
    target: Cloud, source: Cloud, pairs: list
) -> tuple[np.ndarray, np.ndarray]:
    """The pairs in world coordinates, as the pairs file holds them."""
    t = np.array([p[0] for p in pairs], float).reshape(-1, 3) + target.offset
    s = np.array([p[1] for p in pairs], float).reshape(-1, 3) + source.offset
    return t, s


def local_pairs(
    target: Cloud, source: Cloud, t_world: np.ndarray, s_world: np.ndarray
) -> list[tuple[np.ndarray, np.ndarray]]:
    """World pairs read from a file as local points of each scan."""
    return [
        (np.asarray(a - target.offset), np.asarray(b - source.offset))
        for a, b in zip(t_world, s_world, strict=True)
    ]


def ghosts(
    target: Cloud, source: Cloud, T: np.ndarray, n: int
) -> tuple[np.ndarray, np.ndarray]:
    """Every k-th point (about ``n``) of each scan moved into the other's frame by
    the rough pose ``T`` (local T_target_source): (source in the target's view,
    target in the source's)."""
    s_xyz = source.xyz[:: max(1, len(source) // n)]
    t_xyz = target.xyz[:: max(1, len(target) // n)]
    inv = np.linalg.inv(T)
    return (
        s_xyz @ T[:3, :3].T + T[:3, 3],
        t_xyz @ inv[:3, :3].T + inv[:3, 3],
    )
