"""The plot's stand figures from its inventory rows, as a forester sums a tally sheet.

A tree marked *not a tree* does not count; a DBH measured by hand stands in for the
measured one. Heights count only where some scan saw above the top (``height_flag``
``ok``): the others are lower bounds.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

from amrst.plot.review import NOT_A_TREE

if TYPE_CHECKING:
    from collections.abc import Mapping, Sequence


@dataclass(frozen=True, slots=True)
class Stand:
    """Stand figures of the trees listed (not per hectare: the plot has no edge)."""

    trees: int  # listed and not marked not a tree
    with_dbh: int  # of them, with a DBH (measured or by hand)
    basal_area_m2: float  # the sum of pi DBH^2 / 4
    qmd_m: float  # quadratic mean DBH
    lorey_height_m: float  # basal-area-weighted mean height of the tops seen
    with_height: int  # trees in that mean


def stand(rows: Sequence[Mapping[str, Any]]) -> Stand:
    """Return the stand figures of inventory rows (``trees.csv``'s columns)."""
    kept = [r for r in rows if r.get("mark") != NOT_A_TREE]
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
    )


def _dbh(row: Mapping[str, Any]) -> float:
    hand = _num(row.get("dbh_hand_m"))
    return hand if math.isfinite(hand) else _num(row.get("dbh_m"))


def _num(value: Any) -> float:
    try:
        v = float(value)
    except (TypeError, ValueError):
        return math.nan
    return v if math.isfinite(v) and v > 0 else math.nan
