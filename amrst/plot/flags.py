"""What the inventory's DBH and height flags mean, from the limits it used.

One wording for trees.xlsx's columns sheet, the report's legend and the Plot
window's tooltips.
"""

from __future__ import annotations

import math

from amrst.plot.stemmap import OUTLIER_NEAR_M, OUTLIER_OFF_M, StemMapParams

_P = StemMapParams()

#: Which points a DBH's outlier share counts.
OUTLIER_SHARE = (
    f"of the slice's points within {OUTLIER_NEAR_M * 100:g} cm of the circle, the "
    f"share over {OUTLIER_OFF_M * 100:g} cm off it (farther points, a neighbour or a "
    "branch end, do not count)"
)

#: When a DBH is ok.
DBH_OK = (
    f"its circle's points cover an arc of {_P.ok_arc_deg:g}° or more of the stem "
    f"({_P.wide_ok_arc_deg:g}° of a stem over {_P.wide_stem_m * 100:g} cm, seldom "
    f"round), fit within {_P.ok_rmse_m * 1000:g} mm RMS, at most "
    f"{_P.ok_outlier_share:.0%} of the points near it off it, and the slices from 1 "
    "to 1.6 m agree on it"
)
#: What a DBH to check asks for.
DBH_CHECK = "measure it by hand before you use it (dbh_why says which check failed)"
#: Each height flag but ok, and what sets it.
HEIGHT_FLAGS = {
    "lean": f"the stem leans over {_P.lean_flag_deg:g}°, or the top stands over "
    f"{_P.top_lean_flag_deg:g}° off the vertical over its foot (a bent tree, or a "
    "neighbour's crown taken as its top), or, for a conifer placed where its "
    f"branches point, over {_P.conifer_top_off_m:g} m off that point",
    "top not seen": "no scan saw the space above its top, its crown reaches the edge "
    "of every scan's range, or few points lie in its top metre, so the top may be "
    "hidden (the height too low) or a neighbour's (too high); this flag wins over "
    "lean, and lean_deg still gives the stem's lean",
    "top out of range": "its highest point lies at the edge of every scan's range: "
    "the crown goes on beyond what the scans kept, so no height is given "
    "(height_seen_m: how high it was seen; the tree is taller)",
    "top not checked": "no scan says where its scanner stood (a georeferenced LAS, "
    "say; amrst plot --scanner or the Plot window's Scanner at… gives it), so no top "
    "could be checked",
    "not measured": "no height",
}


def height_words(height_m: float, height_seen_m: float, digits: int = 1) -> str:
    """Write the height as the inventory gives it, in metres without the unit.

    The figure; ``>`` and how high the tree was seen where its top was out of range;
    ``–`` where there is neither.
    """
    if math.isfinite(height_m):
        return f"{height_m:.{digits}f}"
    if math.isfinite(height_seen_m):
        return f">{height_seen_m:.{digits}f}"
    return "–"
