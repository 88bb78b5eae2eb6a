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
