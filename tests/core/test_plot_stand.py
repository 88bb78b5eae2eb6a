"""amrst.plot.stand: the stand figures a forester sums from the inventory."""

from __future__ import annotations

import math

import pytest

from amrst.errors import InvalidInput
from amrst.plot.stand import PlotArea, stand, stand_line


def _row(dbh: str, height: str, flag: str = "ok", mark: str = "", hand: str = ""):
    return {
        "x_m": "0",
        "y_m": "0",
        "dbh_m": dbh,
        "height_m": height,
        "height_flag": flag,
        "mark": mark,
        "dbh_hand_m": hand,
    }


def test_stand_figures_count_the_technician_s_judgement() -> None:
    rows = [
        _row("0.2", "20"),
        _row("0.4", "30", hand="0.3"),  # the DBH by hand stands in
        _row("", "5", flag="top not seen"),  # no DBH, height a lower bound
        _row("0.5", "25", mark="not a tree"),  # left out
        _row("nan", "12", flag="lean"),
    ]
    st = stand(rows)
    assert st.trees == 4
    assert st.with_dbh == 2
    g = [math.pi * d * d / 4 for d in (0.2, 0.3)]
    assert st.basal_area_m2 == pytest.approx(sum(g))
    assert st.qmd_m == pytest.approx(math.sqrt((0.2**2 + 0.3**2) / 2))
    assert st.lorey_height_m == pytest.approx((g[0] * 20 + g[1] * 30) / sum(g))
    assert st.with_height == 2


def test_a_stand_of_no_measured_tree_has_no_means() -> None:
    st = stand([_row("", "", flag="top not seen")])
    assert (st.trees, st.with_dbh, st.basal_area_m2) == (1, 0, 0.0)
    assert math.isnan(st.qmd_m)
    assert math.isnan(st.lorey_height_m)


def test_a_fixed_radius_plot_counts_the_trees_inside_per_hectare() -> None:
    area = PlotArea((100.0, 200.0), 10.0)
    inside = {**_row("0.3", "20"), "x_m": "106", "y_m": "208"}  # 10 m: on the edge
    outside = {**_row("0.5", "25"), "x_m": "100", "y_m": "210.5"}
    nowhere = {**_row("0.4", "25"), "x_m": "", "y_m": ""}
    st = stand([inside, outside, nowhere], area)
    assert (st.trees, st.outside) == (1, 2)
    assert st.hectares == pytest.approx(math.pi * 100 / 1e4)
    assert st.trees_per_ha == pytest.approx(1 / st.hectares)
    assert st.basal_area_m2_per_ha == pytest.approx(math.pi * 0.3**2 / 4 / st.hectares)
    assert PlotArea.from_dict(area.as_dict()) == area
    assert PlotArea.from_dict(None) is None
    for bad in ("wide", True, 10**400, -1.0):  # a plot.json edited by hand
        with pytest.raises(InvalidInput, match=r"plot_area|plot radius"):
            PlotArea.from_dict({**area.as_dict(), "radius_m": bad})
    assert math.isnan(stand([inside]).trees_per_ha)  # no area, no per hectare
    # One tree in a wide plot is no "0 stems/ha".
    wide = PlotArea((100.0, 200.0), 500.0)
    assert ": 0.013\u00a0stems/ha" in stand_line(stand([inside], wide), wide)
    assert ": 32\u00a0stems/ha" in stand_line(stand([inside], area), area)


@pytest.mark.parametrize("radius", [0.0, -5.0, math.nan, math.inf, 1e5])
def test_a_plot_radius_that_is_no_distance_is_refused(radius: float) -> None:
    with pytest.raises(InvalidInput, match="plot radius"):
        PlotArea((0.0, 0.0), radius)
