"""Field scenes for the virtual scanner: ground, neighbours, shrubs, the clip, truth."""

from __future__ import annotations

import json

import numpy as np
import pytest

from amrst.errors import InvalidInput
from amrst.simulate import trunk_base
from amrst.simulate.field import (
    GROUND,
    OTHER,
    TREE,
    FieldOptions,
    field_scene,
    simulate_field_pair,
)
from amrst.types import apply_transform


def test_scene_stands_everything_on_the_ground(tiny_tree) -> None:
    opts = FieldOptions(neighbours=(tiny_tree,), shrubs=2, clip_radius_m=3.0)
    scene = field_scene(tiny_tree, opts, seed=1)
    labels = scene.labels
    assert {TREE, GROUND, OTHER} <= set(np.unique(labels).tolist())
    assert np.sum(labels == TREE) == len(tiny_tree)
    # The tree's foot (as trunk_base finds it) is on the ground, sunk 5 cm into it.
    tree = scene.cloud.xyz[labels == TREE]
    assert trunk_base(tree)[2] == pytest.approx(scene.base[2] - 0.05, abs=1e-6)
    ground = scene.cloud.xyz[labels == GROUND]
    assert np.hypot(ground[:, 0], ground[:, 1]).max() <= 4.0 + 0.05


def test_pair_is_clipped_and_its_truth_exact(tiny_tree) -> None:
    opts = FieldOptions(neighbours=(tiny_tree,), shrubs=2, clip_radius_m=3.0)
    pair, info = simulate_field_pair(
        tiny_tree, opts, seed=2, res_deg=0.1, noise_m=0.0, distance_m=6.0
    )
    for role in ("target", "source"):
        cloud = getattr(pair, role)
        in_scene = apply_transform(getattr(pair, f"T_tree_{role}"), cloud.xyz)
        assert np.hypot(in_scene[:, 0], in_scene[:, 1]).max() <= 3.0 + 1e-9
        assert info[f"labels_{role}"]["ground"] > 0
        assert sum(info[f"labels_{role}"].values()) == len(cloud)
    # Points both scans kept land on each other under the truth (no noise).
    both, it, is_ = np.intersect1d(
        pair.index_target, pair.index_source, return_indices=True
    )
    assert len(both) > 100
    moved = apply_transform(pair.T_target_source, pair.source.xyz[is_])
    np.testing.assert_allclose(moved, pair.target.xyz[it], atol=1e-6)
    assert info["clip_radius_m"] == 3.0
    json.dumps(info)  # truth.json-ready


def test_bad_field_options_say_what_to_change() -> None:
    with pytest.raises(
        InvalidInput, match="clip_radius_m must be a number more than 0"
    ):
        FieldOptions(clip_radius_m=-1.0)
    with pytest.raises(InvalidInput, match="neighbour distances"):
        FieldOptions(neighbour_distance_m=(5.0, 2.0))


def test_a_sparse_trunk_under_a_dense_crown_is_the_foot() -> None:
    rng = np.random.default_rng(0)
    trunk = np.column_stack(
        [rng.normal(0, 0.05, (400, 2)), rng.uniform(0.0, 1.7, 400)]
    )  # 0.5 % of the tree
    crown = np.column_stack(
        [rng.normal(0, 1.5, (75_000, 2)), rng.uniform(1.7, 6.0, 75_000)]
    )
    strays = np.column_stack([rng.normal(0, 2, (5, 2)), rng.uniform(-1.5, -0.5, 5)])
    base = trunk_base(np.vstack([strays, trunk, crown]))
    assert base[2] == pytest.approx(0.0, abs=0.05)  # not the crown's base, no stray
    assert np.hypot(*base[:2]) < 0.05


def test_a_slope_alone_asks_for_the_field_scene_with_its_ground() -> None:
    import argparse

    from amrst.simulate.cli import _field_options

    def given(**kw: object) -> argparse.Namespace:
        none = {"ground": False, "neighbours": [], "shrubs": None}
        return argparse.Namespace(**{**none, "clip_radius_m": None, **kw})

    assert _field_options(given(slope_deg=None), None) is None  # a plain case
    options = _field_options(given(slope_deg=5.0), None)
    assert (options.ground, options.slope_deg) == (True, 5.0)
