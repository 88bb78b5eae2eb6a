"""Stem slices: each scan's half of an irregular stem, judged at one common radius."""

from __future__ import annotations

import numpy as np
import pytest

from amrst.review.quality import stem_slices


def _half_stem(facing_deg: float, seed: int) -> np.ndarray:
    """The half of a fluted stem (radius 14 cm +- 1 cm, 0-4 m) a scan faces."""
    rng = np.random.default_rng(seed)
    a = np.radians(facing_deg) + rng.uniform(-np.pi / 2, np.pi / 2, 6000)
    z = rng.uniform(0, 4, len(a))
    r = 0.14 + 0.01 * np.sin(3 * a + 0.5)
    xyz = np.c_[r * np.cos(a), r * np.sin(a), z]
    return xyz + rng.normal(0, 0.002, xyz.shape)


@pytest.mark.parametrize("facing", [(0, 90), (0, 120), (30, 200), (0, 180)])
def test_a_right_pose_reads_good_on_an_irregular_stem(facing) -> None:
    target, source = _half_stem(facing[0], 1), _half_stem(facing[1], 2)
    for s in stem_slices(target, source, (1.3, 3.0)):
        assert s.problem() == ""
        assert s.offset_m < 0.015
        assert s.caption()[1].endswith("mm apart")


@pytest.mark.parametrize("facing", [(0, 90), (0, 120), (30, 200)])
def test_a_shift_along_the_views_bisector_shows(facing) -> None:
    # A shift along the line from one scan's arc to the other's looks like a wider
    # or narrower stem (two half arcs cannot tell them apart); across it, the
    # centres part.
    target, source = _half_stem(facing[0], 1), _half_stem(facing[1], 2)
    bisector = np.radians(np.mean(facing))
    moved = source + 0.03 * np.array([np.cos(bisector), np.sin(bisector), 0.0])
    for s in stem_slices(target, moved, (1.3, 3.0)):
        assert s.offset_m > 0.015
