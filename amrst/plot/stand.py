"""The plot's stand figures from its inventory rows, as a forester sums a tally sheet.

A tree marked *not a tree* does not count; a DBH measured by hand stands in for the
measured one. Heights count only where flagged ``ok`` (``height_flag``): the others
are doubtful (``top not seen``: no scan saw above the top; ``lean``).
With a :class:`PlotArea` (a fixed-radius plot) only the trees whose base lies inside
count, and the figures are also per hectare.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

from amrst.errors import InvalidInput
from amrst.plot.review import NOT_A_TREE
from amrst.types import MAX_COORD_M

if TYPE_CHECKING:
    from collections.abc import Mapping, Sequence

#: Largest plot radius taken (m): a plot is scanned from tripods, not from the air.
MAX_RADIUS_M = 1000.0


@dataclass(frozen=True, slots=True)
class PlotArea:
    """A fixed-radius plot: its centre, as ``trees.csv`` gives positions, and radius.

    Raises
    ------
    InvalidInput
        A radius that is not a number in (0, MAX_RADIUS_M], a centre beyond
        ``MAX_COORD_M``.
    """

    centre_xy: tuple[float, float]
    radius_m: float

    def __post_init__(self) -> None:
        if not 0 < self.radius_m <= MAX_RADIUS_M:  # False for NaN too
            raise InvalidInput(
                f"The plot radius must be a distance in metres above 0 and up to "
                f"{MAX_RADIUS_M:g}, got {self.radius_m!r}."
            )
        if not all(abs(v) <= MAX_COORD_M for v in self.centre_xy):
            raise InvalidInput(
                f"The plot centre must be two coordinates within {MAX_COORD_M:g} m, "
                f"got {self.centre_xy!r}."
            )

    @property
    def hectares(self) -> float:
        """The plot's horizontal area (ha)."""
        return math.pi * self.radius_m**2 / 1e4

    def holds(self, row: Mapping[str, Any]) -> bool:
        """Tell whether the row's stem base lies inside the plot (on its edge too)."""
        x, y = _num(row.get("x_m"), signed=True), _num(row.get("y_m"), signed=True)
        cx, cy = self.centre_xy
        return math.hypot(x - cx, y - cy) <= self.radius_m  # False for NaN

    def as_dict(self) -> dict[str, float]:
        """plot.json's ``plot_area``."""
        return {
            "centre_x_m": self.centre_xy[0],
            "centre_y_m": self.centre_xy[1],
            "radius_m": self.radius_m,
            "hectares": round(self.hectares, 6),
        }

    @classmethod
    def from_dict(cls, doc: Any) -> PlotArea | None:
        """Return plot.json's ``plot_area`` (None for null).

        Raises
        ------
        InvalidInput
            It is there but not a plot area (a field missing, not a number, or out of
            range).
        """
        if doc is None:
            return None
        try:
            values = [doc[k] for k in ("centre_x_m", "centre_y_m", "radius_m")]
            if any(
                isinstance(v, bool) or not isinstance(v, (int, float)) for v in values
            ):
                raise TypeError("not a number")
            x, y, r = (float(v) for v in values)
        except (KeyError, TypeError, ValueError, ArithmeticError) as exc:
            raise InvalidInput(f"plot_area is not a plot area ({exc!r}).") from exc
        return cls((x, y), r)


@dataclass(frozen=True, slots=True)
class Stand:
    """Stand figures of the trees counted; per hectare with the plot's area."""

    trees: int  # counted: listed, not marked not a tree, inside the plot if one
    with_dbh: int  # of them, with a DBH (measured or by hand)
    basal_area_m2: float  # the sum of pi DBH^2 / 4
    qmd_m: float  # quadratic mean DBH
    lorey_height_m: float  # basal-area-weighted mean height of the tops seen
    with_height: int  # trees in that mean
    hectares: float = math.nan  # the plot's area; NaN: not known
    outside: int = 0  # listed trees left out as outside the plot

    @property
    def trees_per_ha(self) -> float:
        """Stems per hectare (NaN without the plot's area)."""
        return self.trees / self.hectares

    @property
    def basal_area_m2_per_ha(self) -> float:
        """Basal area per hectare (NaN without the plot's area)."""
        return self.basal_area_m2 / self.hectares


def stand(rows: Sequence[Mapping[str, Any]], area: PlotArea | None = None) -> Stand:
    """Return the stand figures of inventory rows (``trees.csv``'s columns).

    ``area``: the fixed-radius plot; trees whose base lies outside do not count.
    """
    listed = [r for r in rows if r.get("mark") != NOT_A_TREE]
    kept = listed if area is None else [r for r in listed if area.holds(r)]
    dbh = [_dbh(r) for r in kept]
    areas = [math.pi * d * d / 4 for d in dbh if math.isfinite(d)]
    tall = [
        (math.pi * d * d / 4, _num(r.get("height_m")))
        for r, d in zip(kept, dbh, strict=True)
        if math.isfinite(d)
        and r.get("height_flag") == "ok"
        and math.isfinite(_num(r.get("height_m")))
    ]
    weight = sum(g for g, _ in tall)
    return Stand(
        trees=len(kept),
        with_dbh=len(areas),
        basal_area_m2=sum(areas),
        qmd_m=math.sqrt(4 * sum(areas) / math.pi / len(areas)) if areas else math.nan,
        lorey_height_m=sum(g * h for g, h in tall) / weight if weight else math.nan,
        with_height=len(tall),
        hectares=math.nan if area is None else area.hectares,
        outside=len(listed) - len(kept),
    )


def _dbh(row: Mapping[str, Any]) -> float:
    hand = _num(row.get("dbh_hand_m"))
    return hand if math.isfinite(hand) else _num(row.get("dbh_m"))


def _num(value: Any, *, signed: bool = False) -> float:
    """Return the value as a finite number (positive unless ``signed``), or NaN."""
    try:
        v = float(value)
    except (TypeError, ValueError):
        return math.nan
    return v if math.isfinite(v) and (signed or v > 0) else math.nan


def counted(n: int, noun: str) -> str:
    """``n`` and the noun, plural unless one: "1 tree", "3 trees"."""
    return f"{n} {noun}" if n == 1 else f"{n} {noun}s"


def stand_line(st: Stand, area: PlotArea) -> str:
    """Say the stand inside the plot in one line, as the command and the app do.

    No-break spaces keep each unit on its number's line.
    """
    sp = "\u00a0"
    outside = f"; {counted(st.outside, 'listed tree')} outside" if st.outside else ""
    return (
        f"within {area.radius_m:g}{sp}m ({area.hectares:.4f}{sp}ha): "
        f"{counted(st.trees, 'tree')}, "
        f"{st.with_dbh} with a DBH: {_per_ha(st.trees_per_ha)}{sp}stems/ha, "
        f"basal area {st.basal_area_m2_per_ha:.1f}{sp}m²/ha{outside}"
    )


def _per_ha(value: float) -> str:
    """Stems per hectare, whole; two digits under ten (few trees, a wide plot)."""
    return f"{value:.2g}" if value < 9.5 else f"{value:.0f}"
