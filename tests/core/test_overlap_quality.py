"""Distances on the overlap: what only one scan saw does not count against a pose."""

from __future__ import annotations

import numpy as np

from amrst.review.overlap import overlap_distances


def _stem_side(a0: float, a1: float, n: int, seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    a = rng.uniform(a0, a1, n)
    z = rng.uniform(0, 3, n)
    return np.c_[0.2 * np.cos(a), 0.2 * np.sin(a), z] + rng.normal(0, 0.002, (n, 3))


def test_a_right_pose_reads_right_though_each_scan_saw_its_own_side() -> None:
    # Each scan sees 200 deg of the stem; they share 40 deg on each flank.
    target = _stem_side(0.0, np.radians(200), 20_000, 0)
    source = _stem_side(np.radians(160), np.radians(360), 20_000, 1)
    q = overlap_distances(target, source, np.eye(4))
    assert q.median_m < 0.01
    assert q.within_2cm_fraction > 0.8
    assert 0.1 < q.overlap_fraction < 0.6
    far = np.linalg.norm(source - target[:1], axis=1)  # sanity: sides differ
    assert far.max() > 0.3


def test_a_shifted_pose_reads_off() -> None:
    target = _stem_side(0.0, 2 * np.pi, 20_000, 0)
    source = _stem_side(0.0, 2 * np.pi, 20_000, 1)
    T = np.eye(4)
    T[:3, 3] = (0.06, 0.0, 0.0)
    q = overlap_distances(target, source, T)
    assert q.within_2cm_fraction < 0.6
    assert q.median_m > 0.015


def test_no_overlap_gives_nan_not_an_error() -> None:
    target = _stem_side(0.0, 2 * np.pi, 1000, 0)
    T = np.eye(4)
    T[:3, 3] = (50.0, 0.0, 0.0)
    q = overlap_distances(target, target, T)
    assert q.n_points_measured == 0
    assert np.isnan(q.median_m)
    assert overlap_distances(np.zeros((0, 3)), target, np.eye(4)).n_points_measured == 0
