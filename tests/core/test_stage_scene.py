"""Scene understanding: ground, the tree of interest and neighbours, with known answers.

A synthetic stand: a tree (stem of 15 cm radius, crown) on a ground sloped 10 deg, a
neighbour tree 3 m away, a shrub; every point's true label is known.
"""

from __future__ import annotations

import numpy as np
import pytest

from amrst.stages.ground import fit_ground
from amrst.stages.scene import (
    GROUND,
    OTHER,
    OUTSIDE,
    TREE,
    SceneParams,
    understand_scene,
)

SLOPE = np.tan(np.radians(10.0))


def ground_z(xy: np.ndarray) -> np.ndarray:
    return SLOPE * xy[..., 0] + 0.02 * np.sin(3 * xy[..., 1])  # slope plus bumps


def synthetic_tree(
    rng: np.random.Generator, foot_xy: np.ndarray, height: float
) -> np.ndarray:
    """A stem (cylinder surface, its foot 5 cm into the ground) and a crown shell."""
    z0 = float(ground_z(foot_xy)) - 0.05
    t = rng.uniform(0, 2 * np.pi, 3000)
    z = rng.uniform(0, height * 0.7, 3000)
    stem = np.column_stack(
        [foot_xy[0] + 0.15 * np.cos(t), foot_xy[1] + 0.15 * np.sin(t), z0 + z]
    )
    d = rng.normal(size=(3000, 3))
    d /= np.linalg.norm(d, axis=1)[:, None]
    crown = d * [1.5, 1.5, 1.2] + np.r_[foot_xy, z0 + height * 0.7]
    return np.vstack([stem, crown])


@pytest.fixture(scope="module")
def stand() -> tuple[np.ndarray, np.ndarray]:
    """(N, 3) points and (N,) true labels; the tree of interest stands at (0, 0)."""
    rng = np.random.default_rng(1)
    tree = synthetic_tree(rng, np.zeros(2), 6.0)
    neighbour = synthetic_tree(rng, np.array([3.0, 0.5]), 5.0)
    shrub = rng.normal(size=(400, 3)) * [0.3, 0.3, 0.2] + [-2.0, -1.5, 0.0]
    shrub[:, 2] = np.abs(shrub[:, 2]) + ground_z(shrub[:, :2]) + 0.2
    xy = rng.uniform(-4.5, 4.5, (12000, 2))
    xy = xy[np.hypot(xy[:, 0], xy[:, 1]) < 4.5]
    ground = np.column_stack([xy, ground_z(xy) + rng.normal(0, 0.005, len(xy))])
    xyz = np.vstack([tree, neighbour, shrub, ground])
    labels = np.concatenate(
        [
            np.full(len(tree), TREE),
            np.full(len(neighbour), OTHER),
            np.full(len(shrub), OTHER),
            np.full(len(ground), GROUND),
        ]
    )
    return xyz, labels


def test_labels_and_base_on_a_slope(stand) -> None:
    xyz, truth = stand
    scene = understand_scene(xyz, SceneParams())
    assert scene.has_ground
    assert scene.ground_tilt_deg == pytest.approx(10.0, abs=1.0)
    # Ground: nearly every ground point, and only the stem feet besides.
    is_ground = scene.labels == GROUND
    assert np.mean(is_ground[truth == GROUND]) > 0.97
    assert np.mean(truth[is_ground] == GROUND) > 0.97
    # Above the ground, tree and neighbour/shrub are told apart (the stem feet, within
    # ground_dist_m of the ground, are ground by definition).
    above = (truth != GROUND) & (xyz[:, 2] - ground_z(xyz[:, :2]) > 0.2)
    agree = scene.labels[above] == truth[above]
    assert agree.mean() > 0.95, agree.mean()
    assert np.mean(scene.labels[truth == OTHER] == OTHER) > 0.9
    # Two stems (the shrub is too low to be one), the nearest the axis first.
    assert len(scene.stems) == 2
    np.testing.assert_allclose(scene.stems[0].xy, [0, 0], atol=0.05)
    assert scene.stems[0].radius_m == pytest.approx(0.15, abs=0.03)
    # The base is where the stem meets the sloped ground, not the lowest point.
    assert scene.base is not None
    np.testing.assert_allclose(scene.base[:2], [0, 0], atol=0.05)
    assert scene.base[2] == pytest.approx(float(ground_z(np.zeros(2))), abs=0.05)
    assert scene.base[2] > xyz[:, 2].min() + 0.5  # the slope drops 0.8 m across


def test_a_given_stem_picks_the_neighbour(stand) -> None:
    xyz, truth = stand
    scene = understand_scene(xyz, SceneParams(), stem_xy=np.array([3.0, 0.5]))
    np.testing.assert_allclose(scene.stems[0].xy, [3.0, 0.5], atol=0.05)
    tree = scene.labels == TREE
    assert np.mean(truth[tree] == OTHER) > 0.9  # the neighbour's points are "tree" now


def test_a_clean_tree_is_left_as_it_is(tiny_tree) -> None:
    scene = understand_scene(tiny_tree.xyz, SceneParams())
    assert not scene.has_ground
    assert (scene.labels == TREE).all()
    assert scene.keep().all()
    off = understand_scene(tiny_tree.xyz, SceneParams(mode="off"))
    assert (off.labels == TREE).all()


def test_ground_fit_needs_area_and_levels_the_plane(stand) -> None:
    xyz, truth = stand
    kw = {
        "cell_m": 0.5,
        "tol_m": 0.15,
        "max_slope_deg": 20.0,
        "iterations": 300,
        "seed": 0,
    }
    found = fit_ground(xyz, min_area_m2=12.0, **kw)
    assert found.found
    assert found.area_m2 > 30
    h = found.height(xyz[truth == GROUND])
    assert np.percentile(np.abs(h), 95) < 0.05
    # The same points but only a 1.5 m disc of ground: too small to be a ground.
    small = np.hypot(xyz[:, 0] + 3.5, xyz[:, 1]) < 1.5
    assert not fit_ground(xyz[small & (truth == GROUND)], min_area_m2=12.0, **kw).found


def test_bad_params_say_what_to_change() -> None:
    with pytest.raises(ValueError, match="stem_low_m"):
        SceneParams(stem_low_m=2.0, stem_high_m=1.0)
    with pytest.raises(ValueError, match="mode"):
        SceneParams(mode="on")


def test_a_plot_scan_is_cut_around_the_given_stem(stand) -> None:
    """A third tree 9 m away (a plot scan): with the neighbour's stem given, the scan
    is cut 6 m around it as a technician would; the far tree is left out."""
    xyz, _truth = stand
    rng = np.random.default_rng(2)
    far = synthetic_tree(rng, np.array([-8.0, 4.0]), 6.0)
    xy = rng.uniform(-11, 11, (20000, 2))
    ground = np.column_stack([xy, ground_z(xy)])
    plot = np.vstack([xyz, far, ground])
    scene = understand_scene(plot, SceneParams(), stem_xy=np.array([3.0, 0.5]))
    assert scene.has_ground
    outside = scene.labels == OUTSIDE
    np.testing.assert_array_equal(
        outside, np.hypot(plot[:, 0] - 3.0, plot[:, 1] - 0.5) > 6.0
    )
    assert not scene.keep()[len(xyz) : len(xyz) + len(far)].any()
    np.testing.assert_allclose(scene.stems[0].xy, [3.0, 0.5], atol=0.05)
    assert np.isnan(scene.height_m[outside]).all()
