"""A simulation's settings and tree clouds, checked before any work.

Each message names the setting or the file to change.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np

from amrst.errors import InvalidInput

if TYPE_CHECKING:
    from collections.abc import Mapping, Sequence

    from amrst.types import Cloud

MAX_NOISE_M = 0.5
MAX_TILT_DEG = 45.0
# Lengths beyond a tripod scanner's reach (distances, heights, spacings, ranges, clip
# radii; m) are typos, and far larger ones overflow the scene's coordinates.
MAX_LENGTH_M = 1000.0
# Coarsest beam step (deg): a tripod scanner's is a fraction of a degree.
MAX_RES_DEG = 10.0
# Most scanner positions of one simulated case.
MAX_POSITIONS = 50
# Fewest trees on a plot: a stem map of fewer has no layout to register on.
MIN_TREES = 3
# Most shrubs a scene is built with in memory.
MAX_SHRUBS = 1000
MAX_SLOPE_DEG = 45.0
# Largest height of a plot's hills and hollows (m).
MAX_RELIEF_M = 10.0


@dataclass(frozen=True, slots=True)
class Bounds:
    """The values one setting may take.

    low, high : float or None
        The ends of the range (None: open).
    above_low, below_high : bool
        The end itself is refused (``> low``, ``< high``).
    integer : bool
        Only whole numbers (Python or numpy integers).
    unit : str
        Said after the range in messages.
    why : str
        Said after the range in messages, in brackets.
    """

    low: float | None = None
    high: float | None = None
    above_low: bool = False
    below_high: bool = False
    integer: bool = False
    unit: str = ""
    why: str = ""

    def allows(self, value: Any) -> bool:
        """Tell whether ``value`` is a number of the kind and in the range."""
        kinds = (
            (int, np.integer) if self.integer else (int, float, np.integer, np.floating)
        )
        if isinstance(value, bool) or not isinstance(value, kinds):
            return False
        if not self.integer and not math.isfinite(value):
            return False
        low_ok = (
            self.low is None
            or value > self.low
            or (value == self.low and not self.above_low)
        )
        high_ok = (
            self.high is None
            or value < self.high
            or (value == self.high and not self.below_high)
        )
        return bool(low_ok and high_ok)

    def text(self) -> str:
        """Say the range: ``a number more than 0 and at most 10 degrees``."""
        kind = "an integer" if self.integer else "a number"
        unit = f" {self.unit}" if self.unit else ""
        if self.low is None and self.high is None:
            return "a finite number"
        if self.high is None:
            more = "more than" if self.above_low else "of"
            tail = "" if self.above_low else " or more"
            return f"{kind} {more} {self.low:g}{tail}{unit}"
        if self.low is None:
            less = "under" if self.below_high else "at most"
            return f"{kind} {less} {self.high:g}{unit}"
        if not (self.above_low or self.below_high):
            return f"{kind} from {self.low:g} to {self.high:g}{unit}"
        more = "more than" if self.above_low else "at least"
        less = "under" if self.below_high else "at most"
        return f"{kind} {more} {self.low:g} and {less} {self.high:g}{unit}"


_LENGTH = Bounds(0.0, MAX_LENGTH_M, above_low=True, unit="m")
_POSITIONS = Bounds(2, MAX_POSITIONS, integer=True)

#: What every numeric setting of the simulations may be, by name (the options of
#: ``amrst simulate`` and ``amrst campaign simulate`` are these names with dashes).
SETTINGS: dict[str, Bounds] = {
    "seed": Bounds(0, integer=True),
    "separation_deg": Bounds(-360.0, 360.0, unit="degrees"),
    "distance_m": _LENGTH,
    "height_m": _LENGTH,
    "res_deg": Bounds(0.0, MAX_RES_DEG, above_low=True, unit="degrees"),
    "noise_m": Bounds(
        0.0, MAX_NOISE_M, unit="m", why="a scanner's range noise is millimetres"
    ),
    "tilt_deg": Bounds(
        0.0, MAX_TILT_DEG, unit="degrees", why="a levelled tripod tilts under 1"
    ),
    "slope_deg": Bounds(0.0, MAX_SLOPE_DEG, below_high=True, unit="degrees"),
    "relief_m": Bounds(0.0, MAX_RELIEF_M, unit="m", why="hills a plot stands on"),
    "shrubs": Bounds(0, MAX_SHRUBS, integer=True),
    "clip_radius_m": _LENGTH,
    "positions": _POSITIONS,
    "scans": _POSITIONS,
    "n_scans": _POSITIONS,
    "spacing_m": _LENGTH,
    "range_m": _LENGTH,
    "trees": Bounds(MIN_TREES, integer=True),
}


def _label(name: str, cli: bool) -> str:
    return "--" + name.replace("_", "-") if cli else name


def _shown(value: Any) -> str:
    """Show a value in a message (a huge integer by its size, not its digits)."""
    if isinstance(value, (int, np.integer)) and not isinstance(value, bool):
        v = int(value)
        if abs(v) < 10**15:
            return str(v)
        return f"an integer of about {int(v.bit_length() * math.log10(2)) + 1} digits"
    if isinstance(value, (float, np.floating)):
        return f"{float(value):g}"
    return repr(value)


def check_number(
    name: str, value: Any, *, cli: bool = False, bounds: Bounds | None = None
) -> None:
    """Refuse a value of setting ``name`` out of its range, naming the range.

    Parameters
    ----------
    name : str
        The setting, a key of :data:`SETTINGS` unless ``bounds`` is given.
    value : number
    cli : bool
        Name the setting as a command option (``--res-deg``).
    bounds : Bounds or None
        The range (default: ``SETTINGS[name]``).

    Raises
    ------
    InvalidInput
        ``{name} must be {range}, got {value}.``
    """
    rule = SETTINGS[name] if bounds is None else bounds
    if not rule.allows(value):
        why = f" ({rule.why})" if rule.why else ""
        raise InvalidInput(
            f"{_label(name, cli)} must be {rule.text()}{why}, got {_shown(value)}."
        )


def check_numbers(
    values: Mapping[str, Any], *, cli: bool = False, optional: bool = False
) -> None:
    """Check each setting of ``values`` (name -> value) with :func:`check_number`.

    Each item of a tuple or list is checked; ``optional``: a value of None (an option
    not given) is skipped, else it is refused as any other non-number.
    """
    for name, value in values.items():
        items = value if isinstance(value, (tuple, list)) else [value]
        for item in items:
            if not (optional and item is None):
                check_number(name, item, cli=cli)


def check_range(
    name: str,
    pair: Sequence[Any],
    *,
    cli: bool = False,
    bounds: Bounds | None = None,
) -> None:
    """Refuse a range setting (LOW HIGH, or one value for both) that is not one.

    Raises
    ------
    InvalidInput
        More than two values, an end as :func:`check_number` says, or LOW above
        HIGH.
    """
    if len(pair) not in (1, 2):
        raise InvalidInput(
            f"{_label(name, cli)} takes one value or a range LOW HIGH, got "
            f"{len(pair)} values."
        )
    for value in pair:
        check_number(name, value, cli=cli, bounds=bounds)
    if pair[0] > pair[-1]:
        raise InvalidInput(
            f"{_label(name, cli)} must be a range LOW HIGH with LOW <= HIGH, got "
            f"{_shown(pair[0])} and {_shown(pair[-1])}."
        )


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
    seed, separation_deg, res_deg, noise_m, tilt_deg, height_m : number
        Each in its range of :data:`SETTINGS`.
    distance_m : tuple of float
        One or two distances, each in the range of ``distance_m``.
    cli : bool
        Name the settings as ``amrst simulate`` options (``--res-deg``).

    Raises
    ------
    InvalidInput
        The first setting that is wrong, and what it must be.
    """
    if len(distance_m) not in (1, 2):
        raise InvalidInput(
            f"{_label('distance_m', cli)} must be one distance or two (target, "
            f"source), got {len(distance_m)}."
        )
    numbers = {
        "seed": seed,
        "separation_deg": separation_deg,
        "distance_m": distance_m,
        "res_deg": res_deg,
        "noise_m": noise_m,
        "tilt_deg": tilt_deg,
        "height_m": height_m,
    }
    check_numbers(numbers, cli=cli)


#: The lowest half metre of one tree's cloud (its trunk, buttresses, low branches and
#: the ground a clip kept round it) spans less than this (m); that of a plot of
#: several trees spans more.
ONE_TREE_FOOT_M = 6.0


def one_tree(cloud: Cloud, path: str) -> Cloud:
    """Return ``cloud`` when it is one tree in metres; refuse a plot of several.

    The truth stands each tree on its lowest points (``trunk_base``, which skips
    strays): several stems there would give one wrong foot, and the trees among them
    would be in the scans but not in the truth.
    """
    from amrst.io.checks import refuse_odd_coordinates
    from amrst.simulate import trunk_base

    refuse_odd_coordinates(cloud, path)  # a tree in millimetres is no tree of metres
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
