"""Tree measurements on synthetic trees with known height, DBH and crown."""

from __future__ import annotations

import math

import numpy as np
import pytest

from amrst.measure import (
    MeasureParams,
    fit_stem_circle,
    measure_registration,
    measure_tree,
)
from amrst.types import Cloud, make_transform

RADIUS = 0.15  # stem radius (m): DBH 30 cm
HEIGHT = 10.0


def _stem(rng, arc=(0.0, 2 * np.pi), n=6000, top=6.0, noise=0.003):
    """Bark points of an upright cylinder over ``arc`` (radians), z from 0 to top."""
    a = rng.uniform(*arc, n)
    z = rng.uniform(0.0, top, n)
    r = RADIUS + rng.normal(0.0, noise, n)
    return np.column_stack([r * np.cos(a), r * np.sin(a), z])


def _crown(rng, n=6000, radius=2.0, z0=6.0):
    """A ball of leaves from z0 up to HEIGHT, centred on the stem."""
    d = rng.normal(size=(n, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    p = d * radius * rng.uniform(0.0, 1.0, (n, 1)) ** (1 / 3)
    p[:, 2] = np.clip(
        p[:, 2] * (HEIGHT - z0) / (2 * radius) + (HEIGHT + z0) / 2, z0, HEIGHT
    )
    p[0] = (0.0, 0.0, HEIGHT)  # the tip
    return p


def _tree(rng, **stem):
    return np.vstack([_stem(rng, **stem), _crown(rng)])


def test_whole_tree_gives_height_dbh_and_crown():
    m = measure_tree(_tree(np.random.default_rng(0)))
    assert m.height_m == pytest.approx(HEIGHT, abs=0.05)
    assert m.dbh_m == pytest.approx(2 * RADIUS, abs=0.004)
    assert m.stem is not None
    assert m.stem.arc_deg > 330
    assert m.stem.rmse_m < 0.005
    assert m.note == ""
    # The crown ball is 4 m across: about pi * 2^2 m2 seen from above.
    assert m.crown_area_m2 == pytest.approx(math.pi * 4, rel=0.08)
    assert m.crown_width_m == pytest.approx(4.0, rel=0.06)


def test_half_a_stem_still_gives_the_dbh_and_says_how_much_was_seen():
    m = measure_tree(_tree(np.random.default_rng(1), arc=(0.0, np.pi)))
    assert m.dbh_m == pytest.approx(2 * RADIUS, abs=0.01)
    assert 150 < m.stem.arc_deg < 185


def test_branches_in_the_slice_do_not_pull_the_stem_circle():
    rng = np.random.default_rng(2)
    # Twigs: scattered points 0.4-0.9 m from the stem at every height.
    a, r = rng.uniform(0, 2 * np.pi, 4000), rng.uniform(0.4, 0.9, 4000)
    twigs = np.column_stack([r * np.cos(a), r * np.sin(a), rng.uniform(0.3, 6, 4000)])
    m = measure_tree(np.vstack([_tree(rng), twigs]))
    assert m.dbh_m == pytest.approx(2 * RADIUS, abs=0.006)


def test_stray_points_do_not_change_the_height():
    rng = np.random.default_rng(3)
    xyz = np.vstack([_tree(rng), [[0.5, 0.3, HEIGHT + 20.0], [3.0, 1.0, -7.0]]])
    assert measure_tree(xyz).height_m == pytest.approx(HEIGHT, abs=0.05)


def test_no_stem_in_view_gives_no_dbh_and_says_why():
    m = measure_tree(_crown(np.random.default_rng(4)) - [0, 0, 5.0])
    assert math.isnan(m.dbh_m)
    assert m.stem is None
    assert "no stem circle" in m.note
    assert "n/a" in m.summary()


def test_a_circle_too_thick_for_the_tree_is_not_taken_for_the_stem():
    # A 3 m tall 'stem' 1.2 m across: height/diameter 2.5, a crown envelope, not bark.
    rng = np.random.default_rng(5)
    a, z = rng.uniform(0, 2 * np.pi, 5000), rng.uniform(0, 3.0, 5000)
    ring = np.column_stack([0.6 * np.cos(a), 0.6 * np.sin(a), z])
    m = measure_tree(ring)
    assert math.isnan(m.dbh_m)
    assert "too thick" in m.note


def test_fit_needs_enough_points_on_an_arc():
    rng = np.random.default_rng(6)
    assert fit_stem_circle(rng.normal(size=(5, 2)), MeasureParams()) is None
    a = rng.uniform(0, 2 * np.pi, 200)
    xy = np.column_stack([np.cos(a), np.sin(a)]) * 0.2 + [400.0, -30.0]
    circle = fit_stem_circle(xy, MeasureParams())
    assert circle.radius_m == pytest.approx(0.2, abs=1e-6)
    assert circle.centre_xy == pytest.approx((400.0, -30.0), abs=1e-6)


def test_the_merged_registration_sees_the_stem_all_round():
    rng = np.random.default_rng(7)
    front = _tree(rng, arc=(-np.pi / 2, np.pi / 2))
    back = _tree(rng, arc=(np.pi / 2, 3 * np.pi / 2))
    # The source was scanned in its own frame: 40 deg turned and 5 m away.
    T = make_transform(
        np.array(
            [
                [math.cos(0.7), -math.sin(0.7), 0],
                [math.sin(0.7), math.cos(0.7), 0],
                [0, 0, 1],
            ]
        ),
        np.array([5.0, -2.0, 0.3]),
    )
    inv = np.linalg.inv(T)
    source_xyz = back @ inv[:3, :3].T + inv[:3, 3]
    out = measure_registration(Cloud(front), Cloud(source_xyz), T)
    assert set(out) == {"target", "source", "merged"}
    for scan in ("target", "source"):
        assert out[scan].stem.arc_deg < 190
    merged = out["merged"]
    assert merged.stem.arc_deg > 330
    assert merged.dbh_m == pytest.approx(2 * RADIUS, abs=0.004)
    assert merged.as_dict()["stem_arc_deg"] == merged.stem.arc_deg


def test_kasa_circle_fits_an_arc_and_refuses_a_line():
    from amrst.geometry import kasa_circle

    a = np.linspace(0.0, 2.0, 40)  # a third of the way round, far from the origin
    xy = np.column_stack([500.0 + 0.3 * np.cos(a), -20.0 + 0.3 * np.sin(a)])
    centre, r2 = kasa_circle(xy, np.median(xy, axis=0))
    assert centre == pytest.approx((500.0, -20.0), abs=1e-9)
    assert np.sqrt(r2) == pytest.approx(0.3, abs=1e-9)
    line = np.column_stack([np.arange(10.0), 2 * np.arange(10.0)])
    assert np.isnan(kasa_circle(line, line.mean(axis=0))[1])
    assert np.isnan(kasa_circle(xy[:2], xy[0])[1])


def test_the_arcs_of_many_circles_are_each_circles_arc():
    """The candidate circles' arcs, taken together, equal arc_deg taken one by one."""
    from amrst.measure.stem import _arcs_deg, arc_deg

    rng = np.random.default_rng(3)
    a = rng.uniform(0.0, 4.0, 400)
    xy = np.column_stack([0.2 * np.cos(a), 0.2 * np.sin(a)])
    xy = np.r_[xy + rng.normal(0.0, 0.004, xy.shape), rng.uniform(-0.4, 0.4, (150, 2))]
    centres = rng.normal(0.0, 0.02, (30, 2))
    radii = rng.uniform(0.15, 0.25, 30)
    inl = [
        np.abs(np.linalg.norm(xy - c, axis=1) - r) <= 0.01
        for c, r in zip(centres, radii, strict=True)
    ]
    keep = np.array([m.sum() >= 2 for m in inl])
    one_by_one = [
        arc_deg(xy[m], c) for m, c in zip(inl, centres, strict=True) if m.sum() >= 2
    ]
    together = _arcs_deg(xy, centres[keep], radii[keep], 0.01)
    assert keep.sum() > 10
    assert np.array_equal(together, one_by_one)
