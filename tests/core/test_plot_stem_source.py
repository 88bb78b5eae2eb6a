"""The stem map registers a plot pair on which the tetrahedra alone go wrong.

Two scans from opposite sides of a plot of bare stems see opposite halves of every
stem: the skeletons run along each half's surface, a stem radius apart, so the key
points of the two scans disagree by up to a diameter and tetrahedra of them fit a
pose degrees off. The stem map fits circles, whose centres both scans agree on.
"""

from __future__ import annotations

import numpy as np
import pytest
from _plots import STEMS, pose, scan

import amrst.pipeline.link as pipeline_link
from amrst.params import RegistrationParams
from amrst.pipeline import analyse_scan, coarse_from_matches, find_matches, refine
from amrst.plot.register import analyse_plot_scan, plot_params, register_plot_link
from amrst.plot.stemmap import StemMapParams
from amrst.types import Cloud, Transform, invert_transform, rotation_angle_deg


def _within(T: Transform, T_true: Transform) -> bool:
    """Within 1 deg and 5 cm of the truth (the benchmark's rule)."""
    E = invert_transform(T_true) @ T
    return bool(rotation_angle_deg(E[:3, :3]) < 1.0 and np.linalg.norm(E[:3, 3]) < 0.05)


@pytest.fixture(scope="module")
def opposite_pair() -> tuple[np.ndarray, np.ndarray, Transform]:
    """Scans from (-7, 0) and (7, 1) of the test plot, and the true T_target_source."""
    target = scan((-7.0, 0.0), STEMS, 1, hidden_tops=True)
    T_true = pose(70.0, (7.0, 1.0, 0.0), tilt_deg=1.0)
    inv = invert_transform(T_true)
    world = scan((7.0, 1.0), STEMS, 2, hidden_tops=True)
    return target, world @ inv[:3, :3].T + inv[:3, 3], T_true


def test_the_tetrahedra_alone_miss_the_pose(opposite_pair, monkeypatch) -> None:
    target, source, T_true = opposite_pair
    monkeypatch.setattr(pipeline_link, "CANDIDATE_SOURCES", ())
    params = RegistrationParams()
    a, b = (analyse_scan(Cloud(x), params) for x in (target, source))
    coarse = coarse_from_matches(find_matches(a, b, params))
    assert coarse is not None
    fine = refine(a, b, coarse.T_target_source, params)
    assert not _within(fine.T_target_source, T_true)


def test_the_stem_map_registers_the_same_pair(opposite_pair) -> None:
    target, source, T_true = opposite_pair
    params = plot_params()
    scans = [
        analyse_plot_scan(Cloud(x), params, StemMapParams()) for x in (target, source)
    ]
    link = register_plot_link(scans[0], scans[1], (0, 1), params).link
    assert link.origin == "stems"
    assert link.verdict == "verified"
    assert link.T_local is not None
    assert _within(link.T_local, T_true)


def test_the_stem_poses_do_not_depend_on_where_the_frame_s_origin_lies(
    opposite_pair,
) -> None:
    # The same pair in coordinates a kilometre off and 300 m up: the tilt is taken
    # out about the stems, not about the origin (which moved the stems metres).
    from amrst.plot.match import stem_poses

    target, source, _ = opposite_pair
    shift = np.array([1000.0, 1000.0, 300.0])
    params = plot_params()
    maps = []
    for at in (np.zeros(3), shift):
        scans = [
            analyse_plot_scan(Cloud(x + at), params, StemMapParams())
            for x in (target, source)
        ]
        maps.append(stem_poses(scans[0].stems, scans[1].stems))
    near, far = maps[0][0], maps[1][0]
    assert len(far.pairs) == len(near.pairs) >= 3
    moved = np.eye(4)
    moved[:3, 3] = shift
    T_far = invert_transform(moved) @ far.T_target_source @ moved  # back home
    assert _within(T_far, near.T_target_source)
