"""Median spacing slab by slab (amrst.io.describe) equals one tree of every point."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial import cKDTree

from amrst.io.describe import _SPACING_SAMPLE, _merge_sorted, median_spacing


def _one_tree(xyz: np.ndarray) -> float:
    """The spacing as it was computed before the slabs: one sort, one tree."""
    rng = np.random.default_rng(0)
    sample = rng.choice(len(xyz), size=min(len(xyz), _SPACING_SAMPLE), replace=False)
    unique, copied_rows = _merge_sorted(xyz)
    copied = copied_rows[sample]
    dist = np.zeros(len(sample))
    if len(unique) >= 2 and not copied.all():
        found, _ = cKDTree(unique).query(xyz[sample[~copied]], k=2)
        dist[~copied] = found[:, 1]
    return float(np.median(dist))


@pytest.mark.parametrize("case", ["plain", "copies", "dense_x", "spread"])
def test_slabs_give_the_spacing_of_one_tree(case: str) -> None:
    rng = np.random.default_rng(1)
    n = 700_000
    xyz = np.round(rng.normal(0, 1, (n, 3)), 3)
    if case == "copies":
        xyz[rng.integers(0, n, n // 4)] = xyz[5]  # a quarter are one point
    elif case == "dense_x":
        xyz[: n // 2, 0] = np.round(rng.normal(0, 1e-4, n // 2), 6)  # thin slabs
    elif case == "spread":
        xyz[:, 0] *= 1000  # far apart along x: neighbours beyond the next slab
    assert median_spacing(xyz) == _one_tree(xyz)


def test_one_x_for_every_row_is_one_slab() -> None:
    xyz = np.zeros((300_000, 3))
    xyz[:, 1] = np.arange(len(xyz)) % 1000 * 0.01
    assert median_spacing(xyz) == 0.0  # every point has copies
    xyz[:1000, 2] = 5 + np.arange(1000)
    assert median_spacing(xyz) == _one_tree(xyz)
