"""Copies found slab by slab (amrst.io.describe) equal one sort of all rows."""

from __future__ import annotations

import numpy as np
import pytest

from amrst.io.describe import _merge_copies, _merge_sorted


def _rows(a: np.ndarray) -> np.ndarray:
    return a[np.lexsort(a.T[::-1])]


@pytest.mark.parametrize(("n", "dup"), [(600_000, 0.0), (700_000, 0.2)])
def test_slabs_find_the_same_copies_as_one_sort(n: int, dup: float) -> None:
    rng = np.random.default_rng(1)
    xyz = np.round(rng.normal(0, 1, (n, 3)), 2)  # cm grid: chance copies too
    if dup:
        xyz[rng.integers(0, n, int(n * dup))] = xyz[5]
    distinct, copied = _merge_copies(xyz)
    distinct_1, copied_1 = _merge_sorted(xyz)
    np.testing.assert_array_equal(copied, copied_1)
    np.testing.assert_array_equal(_rows(distinct), _rows(distinct_1))
    assert copied.any()


def test_one_x_for_every_row_falls_back_to_one_slab() -> None:
    xyz = np.zeros((300_000, 3))
    xyz[:, 1] = np.arange(len(xyz)) % 1000
    distinct, copied = _merge_copies(xyz)
    assert len(distinct) == 1000
    assert copied.all()
