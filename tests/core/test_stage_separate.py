"""Wood-leaf separation on a synthetic tree whose true labels are known."""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
import pytest

from amrst.stages.separate import SeparateParams, separate_wood


class SyntheticTree(NamedTuple):
    xyz: np.ndarray  # (N, 3)
    trunk: np.ndarray  # (N,) bool
    branch: np.ndarray  # (N,) bool
    leaf: np.ndarray  # (N,) bool


def _cylinder_surface(a, b, radius, n, rng, noise=0.0) -> np.ndarray:
    a, b = np.asarray(a, float), np.asarray(b, float)
    d = (b - a) / np.linalg.norm(b - a)
    u = np.cross(d, [1.0, 0, 0] if abs(d[0]) < 0.9 else [0, 1.0, 0])
    u /= np.linalg.norm(u)
    v = np.cross(d, u)
    s = rng.uniform(0, np.linalg.norm(b - a), n)
    phi = rng.uniform(0, 2 * np.pi, n)
    ring = np.cos(phi)[:, None] * u + np.sin(phi)[:, None] * v
    return a + s[:, None] * d + radius * ring + rng.normal(0, noise, (n, 3))


@pytest.fixture(scope="module")
def synthetic_tree() -> SyntheticTree:
    """A 4 m trunk (surface of a 15 cm cylinder), three thin line branches from 3.5 m,
    and a crown of 4,000 leaf points scattered in a 1.5 m sphere around them."""
    rng = np.random.default_rng(0)
    trunk = _cylinder_surface([0, 0, 0], [0, 0, 4], 0.15, 6000, rng, noise=0.002)
    branches = []
    for azimuth in (0.0, 2.1, 4.2):
        d = np.array([np.cos(azimuth), np.sin(azimuth), 0.8])
        d /= np.linalg.norm(d)
        s = rng.uniform(0, 1.8, 500)
        branches.append([0, 0, 3.5] + s[:, None] * d + rng.normal(0, 0.005, (500, 3)))
    branch = np.vstack(branches)
    v = rng.normal(size=(4000, 3))
    v /= np.linalg.norm(v, axis=1, keepdims=True)
    leaves = [0, 0, 5.5] + 1.5 * v * rng.uniform(0, 1, (4000, 1)) ** (1 / 3)
    xyz = np.vstack([trunk, branch, leaves])
    labels = np.repeat([0, 1, 2], [len(trunk), len(branch), len(leaves)])
    return SyntheticTree(xyz, labels == 0, labels == 1, labels == 2)


@pytest.mark.parametrize("feature_voxel_m", [0.0, 0.06])
def test_geometry_separates_trunk_and_branches_from_leaves(
    synthetic_tree, feature_voxel_m
) -> None:
    """Features at every point, and at one point per 6 cm voxel (the default)."""
    t = synthetic_tree
    xyz = t.xyz.copy()
    xyz.setflags(write=False)
    params = SeparateParams(mode="geometry", feature_voxel_m=feature_voxel_m)
    res = separate_wood(xyz, None, params)
    np.testing.assert_array_equal(xyz, t.xyz)  # input unchanged
    assert res.method == "geometry"
    assert res.is_wood.dtype == bool
    assert res.is_wood.shape == (len(xyz),)
    assert np.isnan(res.intensity_threshold)
    assert 0.03 <= res.curvature_threshold <= 0.09  # the automatic (Otsu) range
    wood = t.trunk | t.branch
    recall_trunk = res.is_wood[t.trunk].mean()
    recall_branch = res.is_wood[t.branch].mean()
    precision = (res.is_wood & wood).sum() / res.is_wood.sum()
    assert recall_trunk > 0.95, f"trunk recall {recall_trunk:.3f}"
    assert recall_branch > 0.85, f"branch recall {recall_branch:.3f}"
    assert precision > 0.97, f"wood precision {precision:.3f}"
    assert res.is_wood[t.leaf].mean() < 0.05
    assert res.wood_fraction == pytest.approx(res.is_wood.mean())


def test_xyz_only_works_in_every_mode(synthetic_tree) -> None:
    """Without intensity, 'auto' and even 'intensity' fall back to geometry."""
    geometry = separate_wood(synthetic_tree.xyz, None, SeparateParams(mode="geometry"))
    for mode in ("auto", "intensity"):
        res = separate_wood(synthetic_tree.xyz, None, SeparateParams(mode=mode))
        assert res.method == "geometry"
        np.testing.assert_array_equal(res.is_wood, geometry.is_wood)


def test_intensity_mode_separates_by_intensity(synthetic_tree) -> None:
    """On the trunk alone (all smooth wood), bright lower half vs dark upper half:
    geometry calls all of it wood, intensity mode follows the intensity."""
    rng = np.random.default_rng(1)
    xyz = synthetic_tree.xyz[synthetic_tree.trunk]
    lower = xyz[:, 2] < 2.0
    intensity = np.where(lower, 200.0, 50.0) + rng.normal(0, 5, len(xyz))
    res = separate_wood(xyz, intensity, SeparateParams(mode="intensity"))
    assert res.method == "intensity"
    assert 60.0 < res.intensity_threshold < 190.0  # between the two modes
    assert res.is_wood[lower].mean() > 0.98
    assert res.is_wood[~lower].mean() < 0.02
    # Swapping bright and dark swaps the labels: the intensity decides, not the shape.
    swapped = separate_wood(xyz, 250.0 - intensity, SeparateParams(mode="intensity"))
    assert swapped.is_wood[~lower].mean() > 0.98
    assert swapped.is_wood[lower].mean() < 0.02
    geometry = separate_wood(xyz, intensity, SeparateParams(mode="geometry"))
    assert geometry.method == "geometry"
    assert geometry.is_wood.mean() > 0.95


def test_fixed_intensity_threshold_is_used(synthetic_tree) -> None:
    xyz = synthetic_tree.xyz[synthetic_tree.trunk]
    intensity = xyz[:, 2] * 100.0  # 0..400 along the trunk
    res = separate_wood(
        xyz, intensity, SeparateParams(mode="intensity", intensity_threshold=300.0)
    )
    assert res.intensity_threshold == 300.0
    assert res.is_wood[xyz[:, 2] > 3.2].mean() > 0.98
    assert res.is_wood[xyz[:, 2] < 2.8].mean() < 0.02


def test_all_wood_labels_everything_wood(synthetic_tree) -> None:
    res = separate_wood(synthetic_tree.xyz, None, SeparateParams(mode="all_wood"))
    assert res.method == "all_wood"
    assert res.is_wood.dtype == bool
    assert res.is_wood.all()
    assert len(res.is_wood) == len(synthetic_tree.xyz)
    assert res.wood_fraction == 1.0


@pytest.mark.parametrize(
    "bad", [{"mode": "magic"}, {"scales_k": ()}, {"scales_k": (3, 30)}]
)
def test_params_are_validated(bad) -> None:
    with pytest.raises(ValueError, match=r"mode|scales_k"):
        SeparateParams(**bad)
