"""Manual recovery maths: known answers for the pair fits, the nudge and parsing."""

from __future__ import annotations

import json

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from amrst.errors import InvalidInput
from amrst.review import manual
from amrst.types import rotation_angle_deg


def _pose(rotvec_deg, t) -> np.ndarray:
    T = np.eye(4)
    T[:3, :3] = Rotation.from_rotvec(np.radians(rotvec_deg)).as_matrix()
    T[:3, 3] = t
    return T


SRC = np.array([[0.0, 0.0, 0.0], [1.0, 0.2, 0.5], [0.3, 2.0, 1.0], [-1.0, 0.5, 4.0]])


def test_kabsch_recovers_a_known_pose_from_three_pairs():
    T_true = _pose([10, -20, 95], [4.0, -2.5, 0.7])
    tgt = SRC[:3] @ T_true[:3, :3].T + T_true[:3, 3]
    fit = manual.fit_pairs(tgt, SRC[:3])
    np.testing.assert_allclose(fit.T_target_source, T_true, atol=1e-9)
    assert fit.rmse_m < 1e-9
    assert not fit.levelled


def test_kabsch_never_returns_a_reflection():
    # Mirrored targets: the best proper rotation, not the mirror.
    tgt = SRC * np.array([1, 1, -1])
    T = manual.fit_rigid(tgt, SRC)
    assert np.linalg.det(T[:3, :3]) == pytest.approx(1.0)


def test_residuals_name_the_bad_pair():
    T_true = _pose([0, 0, 30], [1.0, 2.0, 0.0])
    src = np.vstack([SRC, SRC[1:] + np.array([2.0, -1.0, 1.0])])
    tgt = src @ T_true[:3, :3].T + T_true[:3, 3]
    tgt[3] += [0.0, 0.5, 0.0]  # one mis-picked pair
    fit = manual.fit_pairs(tgt, src)
    assert int(np.argmax(fit.residuals_m)) == 3
    assert fit.rmse_m > 0.1


def test_levelled_two_pairs_give_yaw_and_shift():
    T_true = _pose([0, 0, -137], [3.0, 1.0, -0.5])
    tgt = SRC[:2] @ T_true[:3, :3].T + T_true[:3, 3]
    fit = manual.fit_pairs(tgt, SRC[:2])
    assert fit.levelled
    np.testing.assert_allclose(fit.T_target_source, T_true, atol=1e-9)


def test_levelled_fit_ignores_tilt_noise_in_height():
    T_true = _pose([0, 0, 60], [0.5, 0.0, 2.0])
    tgt = SRC @ T_true[:3, :3].T + T_true[:3, 3]
    T = manual.fit_pairs(tgt, SRC, levelled=True).T_target_source
    assert rotation_angle_deg(T[:3, :3] @ T_true[:3, :3].T) < 1e-9
    np.testing.assert_allclose(T[2, :3], [0, 0, 1], atol=1e-12)


@pytest.mark.parametrize(
    ("tgt", "src", "words"),
    [
        (SRC[:1], SRC[:1], "needs 3"),
        (SRC[:2], SRC[:3], "counterpart"),
        (np.zeros((2, 3)), np.array([[0, 0, 0], [0, 0, 1.0]]), "source points are"),
        (np.array([[0, 0, 0], [0, 0, 1.0]]), SRC[:2], "target points are on one"),
    ],
)
def test_too_few_or_degenerate_pairs_say_what_to_pick(tgt, src, words):
    with pytest.raises(InvalidInput, match=words):
        manual.fit_pairs(tgt, src)


def test_collinear_pairs_are_refused_for_the_full_fit():
    line = np.array([[0, 0, 0], [1, 0, 0], [2, 0, 0.0]])
    with pytest.raises(InvalidInput, match="line"):
        manual.fit_rigid(line, line)


def test_nudge_turns_about_the_pivot_and_shifts():
    pivot = np.array([2.0, 3.0, 0.0])
    T = manual.nudge(np.eye(4), yaw_deg=90, shift_m=(0.1, 0, 0), pivot=pivot)
    # The pivot stays (then shifts); a point 1 m east of it goes 1 m north.
    np.testing.assert_allclose(
        T[:3, :3] @ pivot + T[:3, 3], pivot + np.array([0.1, 0, 0])
    )
    p = pivot + np.array([1.0, 0, 0])
    np.testing.assert_allclose(
        T[:3, :3] @ p + T[:3, 3], pivot + np.array([0.1, 1.0, 0])
    )


def test_parse_transform_reads_what_the_export_writes():
    T = _pose([3, 4, 50], [1.25, -3.5, 0.125])
    as_json = json.dumps({"T_target_source": T.tolist(), "verified": False})
    np.testing.assert_allclose(manual.parse_transform(as_json), T)
    text = "# T_target_source\n" + "\n".join(
        " ".join(f"{v:.12f}" for v in r) for r in T
    )
    np.testing.assert_allclose(manual.parse_transform(text), T, atol=1e-11)
    np.testing.assert_allclose(manual.parse_transform(json.dumps(T.tolist())), T)


@pytest.mark.parametrize(
    ("text", "words"),
    [
        ("1 2 3\n4 5 6", "4 rows of 4"),
        ("{}", "no T_target_source"),
        ("{bad", "not valid JSON"),
        ("1 0 0 0\n0 2 0 0\n0 0 1 0\n0 0 0 1", "not a rotation"),
        ("a b c d", "not a row of numbers"),
        ("1 0 0 1e300\n0 1 0 0\n0 0 1 0\n0 0 0 1", "farther than any two scans"),
        ("1 0 0 1e12\n0 1 0 0\n0 0 1 0\n0 0 0 1", "limit 1e\\+08 m"),
    ],
)
def test_parse_transform_refuses_bad_input_with_one_line(text, words):
    with pytest.raises(InvalidInput, match=words):
        manual.parse_transform(text)


def test_a_manual_pose_is_scored_like_the_automatic_ones():
    from amrst.stages.coarse import CoarseParams

    rng = np.random.default_rng(1)
    target = rng.uniform(-1, 1, (3000, 3)) * [1, 1, 5]
    T_true = _pose([0, 0, 40], [1.0, 0.5, 0.0])
    source = (target - T_true[:3, 3]) @ T_true[:3, :3]  # target = T source
    right = manual.score_manual(T_true, target, source, CoarseParams(), 10**6, "test")
    wrong = manual.score_manual(
        _pose([0, 0, 160], [1.0, 0.5, 0.0]), target, source, CoarseParams(), 10**6, "x"
    )
    assert right.origin == "manual"
    assert right.score > 0.9
    assert wrong.score < right.score


def test_turn_swing_is_large_for_points_up_one_stem() -> None:
    from amrst.review.manual import PICK_ERROR_M, turn_swing

    stem = np.array([[0.0, 0.0, 0.0], [0.05, 0.0, 3.0]])
    lever, swing = turn_swing(stem)
    assert lever == pytest.approx(0.025)
    assert swing > 60
    crown = np.vstack([stem, [[3.0, 1.0, 6.0]]])
    lever, swing = turn_swing(crown)
    assert swing == pytest.approx(np.degrees(np.arctan2(PICK_ERROR_M, lever)))
    assert swing < 2
    assert turn_swing(np.zeros((2, 3)))[1] == 180.0
