"""DBH of half-seen, irregular, leaning and field-clipped stems (synthetic clouds)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from amrst.measure import TreeMeasures, dbh_check, measure_registration, measure_tree
from amrst.types import Cloud, make_transform

RADIUS = 0.2  # DBH 40 cm
HEIGHT = 12.0


def _stem(
    rng: np.random.Generator,
    *,
    seen_from: tuple[float, float] | None = None,
    lobes: float = 0.0,
    lean: float = 0.0,
    n: int = 12000,
) -> np.ndarray:
    """Bark of a stem 6 m tall with 3 mm range noise, standing at the origin.

    ``seen_from``: (x, y) of a scanner; only the bark facing it within 75 deg is kept
    (a TLS scan: beams grazing the sides return little).
    ``lobes``: relative depth of three bark lobes (an irregular, non-circular stem).
    ``lean``: horizontal drift of the axis per metre of height (along x).
    """
    a = rng.uniform(0, 2 * np.pi, n)
    z = rng.uniform(0.0, 6.0, n)
    r = RADIUS * (1 + lobes * np.cos(3 * a + 0.4)) + rng.normal(0, 0.003, n)
    xyz = np.column_stack([r * np.cos(a) + lean * z, r * np.sin(a), z])
    if seen_from is not None:
        axis = np.column_stack([lean * z, np.zeros(n)])
        out = xyz[:, :2] - axis
        view = np.asarray(seen_from) - axis
        cos = np.sum(out * view, axis=1) / np.hypot(*out.T) / np.hypot(*view.T)
        xyz = xyz[cos > math.cos(math.radians(75))]
    return xyz


def _crown(rng: np.random.Generator, n: int = 6000) -> np.ndarray:
    """A ball of leaves over the stem, up to HEIGHT."""
    d = rng.normal(size=(n, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    ball = d * 2.5 * rng.uniform(0, 1, (n, 1)) ** (1 / 3) + [0, 0, HEIGHT - 2.5]
    ball[0] = (0, 0, HEIGHT)
    return ball


def _branch(rng: np.random.Generator, z: float, n: int = 400) -> np.ndarray:
    """A branch 8 cm thick leaving the stem at height ``z`` towards +y."""
    t = rng.uniform(RADIUS, 1.2, n)
    a = rng.uniform(0, 2 * np.pi, n)
    return np.column_stack(
        [0.04 * np.cos(a), t, z + 0.3 * (t - RADIUS) + 0.04 * np.sin(a)]
    )


def _ground(
    rng: np.random.Generator, slope: float, radius: float = 4.0, n: int = 30000
) -> np.ndarray:
    """A ground disc around the stem, rising ``slope`` m per m along x."""
    xy = rng.uniform(-radius, radius, (n, 2))
    xy = xy[np.hypot(*xy.T) < radius]
    xy = xy[np.hypot(*xy.T) > RADIUS]
    return np.column_stack([xy, slope * xy[:, 0] + rng.normal(0, 0.005, len(xy))])


def test_a_half_seen_irregular_stem_with_a_branch_gives_its_dbh():
    rng = np.random.default_rng(0)
    tree = np.vstack(
        [
            _stem(rng, seen_from=(8.0, 3.0), lobes=0.04),
            _branch(rng, 1.25),
            _crown(rng),
        ]
    )
    m = measure_tree(tree)
    assert m.dbh_m == pytest.approx(2 * RADIUS, abs=0.025)
    assert 120 < m.stem.arc_deg < 200
    assert m.dbh_doubt == ""


def test_two_scans_arcs_are_fitted_jointly_on_the_merged_tree():
    rng = np.random.default_rng(1)
    front = np.vstack([_stem(rng, seen_from=(8.0, 0.0), lobes=0.05), _crown(rng)])
    back = np.vstack([_stem(rng, seen_from=(-6.0, 4.0), lobes=0.05), _crown(rng)])
    # The source was scanned in its own frame: 40 deg turned and 5 m away.
    c, s = math.cos(0.7), math.sin(0.7)
    T = make_transform(
        np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]]), np.array([5.0, -2.0, 0.3])
    )
    inv = np.linalg.inv(T)
    # The registration is 5 mm off: the two arcs do not quite meet.
    back = back + np.array([0.004, -0.003, 0.0])
    out = measure_registration(
        Cloud(front), Cloud(back @ inv[:3, :3].T + inv[:3, 3]), T
    )
    merged = out["merged"]
    assert merged.stem.arc_deg > 250
    assert merged.dbh_m == pytest.approx(2 * RADIUS, abs=0.015)
    assert dbh_check(out) == ""


def test_a_field_clip_measures_the_middle_stem_from_the_ground_under_it():
    # A clip 4 m around the tree on a 10 % slope: the lowest ground lies 0.4 m below
    # the tree's base, and a thicker neighbour stands 2.5 m away inside the clip.
    rng = np.random.default_rng(2)
    neighbour = _stem(rng, n=20000) * [2.5, 2.5, 1] + [0.0, 2.5, 0.0]
    clip = np.vstack(
        [
            _stem(rng, seen_from=(6.0, -4.0)),
            _stem(rng, seen_from=(-6.0, -4.0)),
            _crown(rng),
            neighbour,
            _ground(rng, slope=0.1),
        ]
    )
    m = measure_tree(clip)
    assert m.stem.centre_xy == pytest.approx((0.0, 0.0), abs=0.03)
    assert m.dbh_m == pytest.approx(2 * RADIUS, abs=0.015)
    assert m.base_z == pytest.approx(0.0, abs=0.05)
    assert m.height_m == pytest.approx(HEIGHT, abs=0.1)


def test_a_leaning_stem_keeps_its_base():
    rng = np.random.default_rng(3)
    tree = np.vstack([_stem(rng, lean=0.5), _crown(rng) + np.array([3.0, 0, 0])])
    m = measure_tree(tree)
    # A vertical cylinder around the stem at breast height would end 0.7 m up the
    # stem, and the height would lose as much.
    assert m.base_z == pytest.approx(0.0, abs=0.02)
    assert m.height_m == pytest.approx(HEIGHT, abs=0.05)
    assert m.dbh_m == pytest.approx(2 * RADIUS, abs=0.01)


def test_a_stem_seen_from_one_side_by_both_scans_is_flagged():
    rng = np.random.default_rng(4)
    tgt = np.vstack([_stem(rng, seen_from=(8.0, 0.5), lobes=0.06), _crown(rng)])
    src = np.vstack([_stem(rng, seen_from=(8.0, -0.5), lobes=0.06), _crown(rng)])
    out = measure_registration(Cloud(tgt), Cloud(src), np.eye(4))
    assert out["merged"].stem.arc_deg < 180
    assert "one side" in dbh_check(out)


def test_slices_that_fit_no_common_circle_make_the_dbh_doubtful():
    # Needle-covered whorls: at each height around 1.3 m a different ring of bark-like
    # points, none the stem.
    rng = np.random.default_rng(5)
    rings = []
    for k, z in enumerate(np.arange(0.9, 1.8, 0.1)):
        r = 0.15 + 0.12 * (k % 3)
        a = rng.uniform(0, 2 * np.pi, 800)
        zz = z + rng.uniform(-0.05, 0.05, 800)
        centre = rng.uniform(-0.3, 0.3, 2)
        rings.append(
            np.column_stack([r * np.cos(a) + centre[0], r * np.sin(a) + centre[1], zz])
        )
    tree = np.vstack([*rings, _stem(rng)[::10] * [1, 1, 0.1], _crown(rng)])
    m = measure_tree(tree)
    assert math.isnan(m.dbh_m) or m.dbh_doubt
    if m.dbh_doubt:
        assert "slices" in m.dbh_doubt
        assert "slices" in dbh_check({"merged": m})


def test_a_ring_of_branches_around_the_stem_is_no_stem():
    # A conifer's branch tips make an upright, bark-like sheet on a ring 76 cm across
    # around a stem seen from one side, with needles between them: the ring holds
    # more points inside it than on it, so it is not the stem.
    rng = np.random.default_rng(7)
    a = rng.uniform(np.radians(-150), np.radians(150), 1500)
    centre, ring = np.array([0.1, 0.0]), 0.38
    tips = np.column_stack(
        [ring * np.cos(a) + centre[0], ring * np.sin(a), rng.uniform(0.9, 2.0, 1500)]
    )
    r = ring * np.sqrt(rng.uniform(0, 1, 6000))
    b = rng.uniform(0, 2 * np.pi, 6000)
    needles = np.column_stack(
        [r * np.cos(b) + centre[0], r * np.sin(b), rng.uniform(0.9, 2.0, 6000)]
    )
    needles = needles[np.hypot(*needles[:, :2].T) > RADIUS + 0.03]
    stem = _stem(rng, seen_from=(8.0, 3.0), n=3000)
    m = measure_tree(np.vstack([stem, tips, needles, _crown(rng)]))
    assert m.stem.centre_xy == pytest.approx((0.0, 0.0), abs=0.03)
    assert m.dbh_m == pytest.approx(2 * RADIUS, abs=0.02)


def test_a_stem_mostly_hidden_at_breast_height_is_measured_on_all_its_bark():
    # Twigs hide the stem from 0.9 to 1.8 m: one scan sees a fifth of its bark there,
    # too little for circles in most slices, but enough in all five together.
    rng = np.random.default_rng(0)
    stem = _stem(rng, seen_from=(8.0, 3.0))
    hidden = (stem[:, 2] > 0.9) & (stem[:, 2] < 1.8)
    r = rng.uniform(RADIUS + 0.05, 0.8, 500)
    a = rng.uniform(0, 2 * np.pi, 500)
    twigs = np.column_stack([r * np.cos(a), r * np.sin(a), rng.uniform(0.9, 1.8, 500)])
    tree = np.vstack([stem[~hidden], stem[hidden][::5], twigs, _crown(rng)])
    m = measure_tree(tree)
    assert m.dbh_m == pytest.approx(2 * RADIUS, abs=0.015)
    assert "show a stem circle" in m.dbh_doubt
    assert "mostly hidden" in dbh_check({"merged": m})


def test_the_doubt_travels_with_the_measures():
    m = measure_tree(_crown(np.random.default_rng(6)))
    assert "dbh_doubt" not in m.as_dict()
    doubtful = TreeMeasures(
        n_points=10,
        base_z=0.0,
        height_m=12.0,
        dbh_m=0.3,
        stem=None,
        crown_area_m2=1.0,
        crown_width_m=1.0,
        note="",
        dbh_doubt="only 2 of the 5 slices fit the same stem circle",
    )
    assert doubtful.as_dict()["dbh_doubt"].startswith("only 2")
    assert dbh_check({"merged": doubtful}).startswith("only 2 of the 5 slices")
