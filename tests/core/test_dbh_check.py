"""A doubtful DBH is flagged, not shown plain."""

from __future__ import annotations

import math

from amrst.measure import StemCircle, TreeMeasures, dbh_check


def _tree(
    dbh: float, height: float = 18.0, arc_deg: float | None = None
) -> TreeMeasures:
    stem = None
    if arc_deg is not None:
        stem = StemCircle((0.0, 0.0), dbh / 2, 0.004, 200, arc_deg)
    return TreeMeasures(
        n_points=1000,
        base_z=0.0,
        height_m=height,
        dbh_m=dbh,
        stem=stem,
        crown_area_m2=10.0,
        crown_width_m=4.0,
        note="",
    )


def test_agreeing_scans_pass() -> None:
    assert (
        dbh_check(
            {"target": _tree(0.30), "source": _tree(0.31), "merged": _tree(0.305)}
        )
        == ""
    )


def test_scans_that_disagree_are_flagged() -> None:
    why = dbh_check(
        {"target": _tree(0.26), "source": _tree(0.36), "merged": _tree(0.35)}
    )
    assert "disagree" in why


def test_a_merged_dbh_away_from_both_scans_is_flagged() -> None:
    why = dbh_check(
        {"target": _tree(1.23), "source": _tree(1.22), "merged": _tree(0.90)}
    )
    assert "differs from each scan" in why


def test_an_implausible_dbh_for_the_height_is_flagged() -> None:
    tree = {k: _tree(1.2, height=6.3) for k in ("target", "source", "merged")}
    assert "implausible" in dbh_check(tree)


def test_no_dbh_is_not_a_doubt() -> None:
    assert dbh_check({"merged": _tree(math.nan)}) == ""


def test_a_merged_circle_on_one_side_of_the_stem_is_flagged() -> None:
    scans = {"target": _tree(0.30), "source": _tree(0.31)}
    assert dbh_check({**scans, "merged": _tree(0.305, arc_deg=250)}) == ""
    why = dbh_check({**scans, "merged": _tree(0.305, arc_deg=160)})
    assert "160° of the stem, one side" in why
