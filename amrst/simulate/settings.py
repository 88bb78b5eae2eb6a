"""A simulation's settings and tree clouds, checked before any work.

Each message names the setting or the file to change.
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING, Any

import numpy as np

from amrst.errors import InvalidInput

if TYPE_CHECKING:
    from amrst.types import Cloud

MAX_NOISE_M = 0.5
MAX_TILT_DEG = 45.0


def check_settings(
    *,
    seed: Any,
    separation_deg: float,
    distance_m: tuple[float, ...],
    res_deg: float,
    noise_m: float,
    tilt_deg: float,
    height_m: float = 1.5,
    cli: bool = False,
) -> None:
    """Refuse settings :func:`simulate_pair` cannot use, naming the setting.

    Parameters
    ----------
    seed : int
        Must be an integer of 0 or more.
    separation_deg, res_deg, noise_m, tilt_deg, height_m : float
        Must be finite; ``res_deg`` > 0, ``noise_m`` and ``tilt_deg`` >= 0.
    distance_m : tuple of float
        One or two finite distances > 0.
    cli : bool
        Name the settings as ``amrst simulate`` options (``--res-deg``).

    Raises
    ------
    InvalidInput
        The first setting that is wrong, and what it must be.
    """

    def label(name: str) -> str:
        return "--" + name.replace("_", "-") if cli else name

    if (
        isinstance(seed, bool)
        or not isinstance(seed, (int, np.integer))
        or int(seed) < 0
    ):
        raise InvalidInput(
            f"{label('seed')} must be an integer of 0 or more, got {seed!r}."
        )
    numbers = {
        "separation_deg": [separation_deg],
        "distance_m": list(distance_m),
        "res_deg": [res_deg],
        "noise_m": [noise_m],
        "tilt_deg": [tilt_deg],
        "height_m": [height_m],
    }
    for name, values in numbers.items():
        for v in values:
            if not isinstance(v, (int, float, np.number)) or not math.isfinite(v):
                raise InvalidInput(
                    f"{label(name)} must be a finite number, got {v!r}; NaN and "
                    "infinity are not allowed."
                )
    if len(distance_m) not in (1, 2) or min(distance_m) <= 0:
        raise InvalidInput(
            f"{label('distance_m')} must be one positive number or two (target, "
            f"source), got {list(distance_m)}."
        )
    if res_deg <= 0:
        raise InvalidInput(f"{label('res_deg')} must be > 0, got {res_deg}.")
    if noise_m < 0 or tilt_deg < 0:
        raise InvalidInput(
            f"{label('noise_m')} and {label('tilt_deg')} must be >= 0, got "
            f"{noise_m} and {tilt_deg}."
        )
    if tilt_deg > MAX_TILT_DEG:
        raise InvalidInput(
            f"{label('tilt_deg')} must be at most {MAX_TILT_DEG} degrees (a levelled "
            f"tripod tilts under 1), got {tilt_deg:g}."
        )
    if noise_m > MAX_NOISE_M:  # a huge noise would write a case with no valid point
        raise InvalidInput(
            f"{label('noise_m')} must be at most {MAX_NOISE_M} m (a scanner's range "
            f"noise is millimetres), got {noise_m:g}."
        )


#: The lowest half metre of one tree's cloud (its trunk, buttresses, low branches and
#: the ground a clip kept round it) spans less than this (m); that of a plot of
#: several trees spans more.
ONE_TREE_FOOT_M = 6.0


def one_tree(cloud: Cloud, path: str) -> Cloud:
    """Return ``cloud`` when it is one tree; refuse a plot of several.

    The truth stands each tree on its lowest points (``trunk_base``, which skips
    strays): several stems there would give one wrong foot, and the trees among them
    would be in the scans but not in the truth.
    """
    from amrst.simulate import trunk_base

    z0 = trunk_base(cloud.xyz)[2]
    z = cloud.xyz[:, 2]
    low = cloud.xyz[(z >= z0) & (z < z0 + 0.5), :2]
    lo, hi = np.percentile(low, [5, 95], axis=0)
    span = float(np.max(hi - lo))
    if span > ONE_TREE_FOOT_M:
        raise InvalidInput(
            f"{path}: its lowest half metre spans {span:.1f} m, as a plot of several "
            "trees does: give one tree a file."
        )
    return cloud
