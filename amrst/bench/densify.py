"""Dense scans from sparse ones, for the benchmarks at real size (``bench-scale``)."""

from __future__ import annotations

import numpy as np

from amrst.errors import InvalidInput
from amrst.types import Cloud


def dense_name(case: str, points: int, noise_m: float, seed: int) -> str:
    """Return the folder name of a case densified to ``points`` a scan.

    Every setting the scans are made with is in it, so a folder made before is reused
    only for the same scans.
    """
    return f"{case}-{points}pts-noise{noise_m * 1000:g}mm-seed{seed}"


def densify(
    cloud: Cloud, n_points: int, noise_m: float = 0.003, seed: int = 0
) -> Cloud:
    """Make an ``n_points`` scan from ``cloud`` by jittered copies of its points.

    Point ``i`` of the result is input point ``i mod N`` plus seeded Gaussian noise of
    ``noise_m`` per axis; attributes are copied along. The first N points are jittered
    too, so no input point survives exactly.

    Parameters
    ----------
    cloud : Cloud
    n_points : int
        Points of the result (>= 1).
    noise_m : float
        Standard deviation of the jitter per axis (m).
    seed : int

    Returns
    -------
    Cloud
        Same offset, name and meta as ``cloud``.
    """
    if len(cloud) == 0:
        raise InvalidInput(f"{cloud.name or 'The scan'} is empty: nothing to densify.")
    if n_points < 1:
        raise InvalidInput(f"Give at least 1 point to make, not {n_points}.")
    rng = np.random.default_rng(seed)
    idx = np.arange(n_points, dtype=np.int64) % len(cloud)
    xyz = cloud.xyz[idx]
    xyz += rng.normal(0.0, noise_m, size=xyz.shape)
    attrs = {k: v[idx] for k, v in cloud.attributes.items()}
    return Cloud(xyz, cloud.offset, attrs, cloud.name, {})
