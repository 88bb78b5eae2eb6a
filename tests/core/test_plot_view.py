"""view.npz: what the app draws of a plot, written and read back as it was."""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np
import pytest

from amrst.errors import InvalidInput
from amrst.plot.view import (
    SLICE_HEIGHTS_M,
    VIEW_NPZ,
    PlotView,
    TopView,
    TreeProfile,
    TreeSlice,
    read_view,
    view_writer,
)

if TYPE_CHECKING:
    from pathlib import Path


def _view(n_trees: int, rng: np.random.Generator) -> PlotView:
    slices = tuple(
        tuple(
            TreeSlice(rng.normal(size=(5 + k + j, 2)), np.full(5 + k + j, k % 2), z)
            for j, z in enumerate(SLICE_HEIGHTS_M)
        )
        for k in range(n_trees)
    )
    profiles = tuple(
        TreeProfile(rng.normal(size=(3 * k, 3)), np.zeros(3 * k, np.int64))
        for k in range(n_trees)
    )
    return PlotView(
        offsets=np.zeros((2, 3)),
        trees=tuple(f"T{k + 1:03d}" for k in range(n_trees)),
        dbh_xy=rng.normal(size=(n_trees, 2)),
        slices=slices,
        profiles=profiles,
        top=TopView(np.zeros((4, 5), np.uint8), -1.0, -2.0, 0.25),
    )


@pytest.mark.parametrize("n_trees", [0, 1, 3])
def test_a_view_reads_back_as_written(tmp_path: Path, n_trees: int) -> None:
    view = _view(n_trees, np.random.default_rng(n_trees))
    view_writer(view)(tmp_path / VIEW_NPZ)
    back = read_view(tmp_path / VIEW_NPZ)
    assert back.trees == view.trees
    assert len(back.profiles) == n_trees  # a tree with no side-view points keeps one
    for a, b in zip(back.profiles, view.profiles, strict=True):
        np.testing.assert_allclose(a.xyz, b.xyz, atol=1e-6)
        assert a.scan.tolist() == b.scan.tolist()
    for ta, tb in zip(back.slices, view.slices, strict=True):
        for a, b in zip(ta, tb, strict=True):
            np.testing.assert_allclose(a.xy, b.xy, atol=1e-6)
            assert a.height_m == b.height_m
    assert back.top is not None
    assert back.top.image.shape == (4, 5)


def test_a_view_whose_parts_disagree_is_one_line(tmp_path: Path) -> None:
    view = _view(2, np.random.default_rng(0))
    bad = PlotView(
        view.offsets, view.trees, view.dbh_xy, view.slices, view.profiles[:1], view.top
    )
    view_writer(bad)(tmp_path / VIEW_NPZ)
    with pytest.raises(InvalidInput, match="run the plot again"):
        read_view(tmp_path / VIEW_NPZ)
