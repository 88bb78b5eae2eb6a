"""Tree measurements stay linear in repeated points.

TLS exports keep no-return points as copies of one position; neighbour counts among a
million copies at the origin would grow with the square of their number, so copies are
measured as one point with its count (``distinct_points``).
"""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np
import pytest

from amrst import io
from amrst.measure import distinct_points, measure_tree

TINY_TREE = Path(__file__).parents[1] / "data" / "tiny_tree" / "tree.ply"


def test_a_million_copies_of_one_point_measure_as_three() -> None:
    tree = io.read(TINY_TREE).world_xyz
    few = measure_tree(np.vstack([tree, np.zeros((3, 3))]))
    many = measure_tree(np.vstack([tree, np.zeros((1_000_000, 3))]))
    assert many.n_points == len(tree) + 1_000_000
    for key in ("height_m", "dbh_m", "crown_area_m2", "crown_width_m", "base_z_m"):
        assert many.as_dict()[key] == few.as_dict()[key], key
    # The copies are one point with its count, so the work stays that of the tree.
    reps, weight = distinct_points(np.vstack([tree, np.zeros((1_000_000, 3))]), 0.001)
    assert len(reps) <= len(tree) + 1
    assert weight.sum() == len(tree) + 1_000_000


@pytest.mark.perf
def test_a_million_copies_of_one_point_cost_about_a_second() -> None:
    tree = io.read(TINY_TREE).world_xyz
    start = time.perf_counter()
    measure_tree(np.vstack([tree, np.zeros((1_000_000, 3))]))
    elapsed = time.perf_counter() - start
    assert elapsed < 8.0, f"{elapsed:.1f} s for 1M copies"


def test_distinct_points_keeps_the_first_of_each_cell_and_counts_copies() -> None:
    xyz = np.array([[0, 0, 0], [1, 1, 1], [0, 0, 0.0001], [1, 1, 1], [2, 0, 0.0]])
    reps, weight = distinct_points(xyz, 0.001)
    np.testing.assert_array_equal(reps, xyz[[0, 1, 4]])
    np.testing.assert_array_equal(weight, [2, 2, 1])
    # Beyond 2**21 cells per axis the keys do not fit one integer: the same answer.
    far = np.vstack([xyz, [[5000.0, 0, 0]]])
    reps, weight = distinct_points(far, 0.001)
    np.testing.assert_array_equal(reps, far[[0, 1, 4, 5]])
    np.testing.assert_array_equal(weight, [2, 2, 1, 1])
