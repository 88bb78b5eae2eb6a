"""The scene layer colours each point by its scene label (no Qt needed)."""

from __future__ import annotations

import numpy as np
import pytest

from amrst.stages.scene import GROUND, OTHER, OUTSIDE, TREE
from amrst_gui.views.layers import SCENE_COLOURS, scene_layer


def test_scene_layer_colours_by_label() -> None:
    xyz = np.arange(12, dtype=float).reshape(4, 3)
    labels = np.array([TREE, GROUND, OTHER, OUTSIDE], dtype=np.int8)
    layer = scene_layer(xyz, labels)
    assert layer.xyz.dtype == np.float32
    np.testing.assert_array_equal(layer.rgb, SCENE_COLOURS[[0, 1, 2, 3]])
    assert len({tuple(c) for c in layer.rgb}) == 4  # four distinct colours
    # The same arrays give the same key: the view does not redraw.
    assert scene_layer(xyz, labels).key == layer.key
    with pytest.raises(ValueError, match="labels"):
        scene_layer(xyz, labels[:2])


def test_the_scan_views_colour_a_field_pair_by_scene(make_main_window, qtbot) -> None:
    """After Separate, "Scene" colours ground, tree and neighbours apart."""
    from pathlib import Path

    from tests.gui._run import run_until_idle

    pair = Path(__file__).resolve().parents[1] / "data" / "field_pair"
    win = make_main_window()
    with qtbot.waitSignals([win.session.scan_loaded] * 2, timeout=20_000):
        win.open_pair(pair / "target.ply", pair / "source.ply")
    qtbot.waitUntil(lambda: not win.session.busy, timeout=10_000)
    assert run_until_idle(win.session, lambda: win.session.run_step("separate")) == []
    pane = win.scans_area.panes["target"]
    pane.colour.setCurrentIndex(pane.colour.findData("scene"))
    qtbot.waitUntil(
        lambda: (
            pane.view.scene is not None
            and any(
                layer.key[0] == "scene"
                for layer in pane.view.scene.layers
                if layer.name == "points"
            )
        ),
        timeout=10_000,
    )
    points = next(layer for layer in pane.view.scene.layers if layer.name == "points")
    colours = {tuple(c) for c in points.rgb}
    # The field pair holds ground and a tree at least, each in its own colour.
    assert tuple(SCENE_COLOURS[GROUND]) in colours
    assert tuple(SCENE_COLOURS[TREE]) in colours
    title = next(layer for layer in pane.view.scene.layers if layer.name == "title")
    assert "brown ground" in title.text


def test_both_scan_views_share_one_height_scale() -> None:
    """The same height above the lowest point is the same colour in both views."""
    from amrst.types import Cloud
    from amrst_gui.views.scene import ViewOptions, build_scan_scene

    class _Two:
        def __init__(self, target: Cloud, source: Cloud) -> None:
            self.clouds = {"target": target, "source": source}
            self.selected_match = None

        def cloud(self, role: str) -> Cloud:
            return self.clouds[role]

        def analysis(self, role: str) -> None:
            return None

        def path(self, role: str) -> None:
            return None

    z = np.linspace(0.0, 1.0, 101)
    tall = Cloud(np.column_stack([z, z, 20.0 * z]))  # 0-20 m
    short = Cloud(np.column_stack([z, z, 100.0 + 10.0 * z]))  # 10 m, higher up
    both = _Two(tall, short)

    def rgb_at(role: str, height_m: float) -> tuple[int, ...]:
        scene = build_scan_scene(both, role, ViewOptions())
        points = next(lay for lay in scene.layers if lay.name == "points")
        z = points.xyz[:, 2] - points.xyz[:, 2].min()
        return tuple(points.rgb[int(np.argmin(np.abs(z - height_m)))])

    assert rgb_at("target", 10.0) == rgb_at("source", 10.0)
    assert rgb_at("source", 10.0) != rgb_at("target", 20.0)  # the short tree's top
