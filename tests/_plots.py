"""A synthetic forest plot for tests: rough ground and upright stems, seen from a spot.

Shared by the engine's and the app's plot tests; imported as ``_plots`` (this folder
is on ``sys.path`` because it holds ``conftest.py``).
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    from collections.abc import Callable

# (x, y, radius, height) of the stems, in the plot's frame.
STEMS = (
    (0.0, 4.0, 0.15, 6.0),
    (5.0, 1.0, 0.22, 7.0),
    (-4.0, -3.0, 0.10, 5.0),
    (2.0, -5.0, 0.18, 6.5),
    (-6.0, 3.5, 0.12, 5.5),
    (6.5, -4.0, 0.25, 7.5),
)


def ground_z(xy: np.ndarray) -> np.ndarray:
    """Height of the gently sloped ground under ``xy`` (..., 2)."""
    return np.asarray(0.03 * xy[..., 0] - 0.02 * xy[..., 1])


def wave_z(xy: np.ndarray) -> np.ndarray:
    """Height of a ground that bends: waves of 0.6 m over 14 m on the gentle slope."""
    return np.asarray(ground_z(xy) + 0.6 * np.sin(2 * np.pi * xy[..., 0] / 14.0))


def scan(
    position: tuple[float, float],
    stems: tuple[tuple[float, ...], ...],
    seed: int,
    hidden_tops: bool = False,
    ground: Callable[[np.ndarray], np.ndarray] = ground_z,
    reach_m: float = np.inf,
) -> np.ndarray:
    """Points a scanner at ``position`` sees: ground, and the near half of each stem.

    ``hidden_tops``: each stem is seen up to a random height only (crowns hide the
    rest differently from each position). ``ground`` gives the ground's height,
    seen within ``reach_m`` of the position.
    """
    rng = np.random.default_rng(seed)
    g = np.mgrid[-12:12:0.08, -12:12:0.08].reshape(2, -1).T
    far = np.hypot(*(g - position).T)
    g = g[(far > 1.0) & (far <= reach_m)]
    parts = [np.column_stack([g, ground(g)])]
    p = np.asarray(position, float)
    for x, y, r, h in stems:
        c = np.array([x, y])
        facing = np.arctan2(*(p - c)[::-1])
        theta = facing + np.linspace(-np.pi / 2, np.pi / 2, int(np.pi * r / 0.01))
        z0 = float(ground(c))
        top = rng.uniform(2.0, h) if hidden_tops else h
        z = np.arange(z0 - 0.05, z0 + top, 0.02)
        tt, zz = np.meshgrid(theta, z)
        parts.append(
            np.column_stack(
                [x + r * np.cos(tt.ravel()), y + r * np.sin(tt.ravel()), zz.ravel()]
            )
        )
    xyz = np.vstack(parts)
    return xyz + rng.normal(0, 0.002, xyz.shape)


def pose(yaw_deg: float, shift: tuple[float, float, float], tilt_deg: float = 0.0):
    """T of a scan: a turn about z, a tilt about x, then a shift."""
    a, t = np.radians(yaw_deg), np.radians(tilt_deg)
    Rz = np.array([[np.cos(a), -np.sin(a), 0], [np.sin(a), np.cos(a), 0], [0, 0, 1]])
    Rx = np.array([[1, 0, 0], [0, np.cos(t), -np.sin(t)], [0, np.sin(t), np.cos(t)]])
    T = np.eye(4)
    T[:3, :3] = Rz @ Rx
    T[:3, 3] = shift
    return T


def blob(
    centre: tuple[float, float, float], radius: float, n: int, seed: int
) -> np.ndarray:
    """``n`` points spread through a ball (leaves, a piece of crown)."""
    rng = np.random.default_rng(seed)
    d = rng.normal(size=(n, 3))
    d /= np.linalg.norm(d, axis=1)[:, None]
    return np.asarray(centre) + d * radius * rng.uniform(0, 1, (n, 1)) ** (1 / 3)


def plot_pair() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Target and source scans of one plot (each in its own frame), true T_target_source.

    The source stands 5 m from the target, turned 70 deg and tilted 1 deg; crowns hide
    each stem's top at another height from each position.
    """
    target = scan((-2.0, 0.0), STEMS, 1, hidden_tops=True)
    T_plot_source = pose(70.0, (3.0, 1.0, 0.0), tilt_deg=1.0)
    world = scan((3.0, 1.0), STEMS, 2, hidden_tops=True)
    T_source_plot = np.linalg.inv(T_plot_source)
    return target, world @ T_source_plot[:3, :3].T + T_source_plot[:3, 3], T_plot_source
