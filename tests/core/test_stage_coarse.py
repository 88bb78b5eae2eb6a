"""Verification, ranking and the coarse choice: on hand-made matches with one right
transform, and on the bundled sample pair with default parameters."""

from __future__ import annotations

import numpy as np
import pytest

from amrst.errors import RegistrationFailed
from amrst.stages.coarse import (
    CandidateList,
    CoarseParams,
    choose_coarse,
    rank_candidates,
)
from amrst.stages.match import TetraMatches
from amrst.types import apply_transform, invert_transform, make_transform


def _rot_z(deg: float) -> np.ndarray:
    from scipy.spatial.transform import Rotation

    return Rotation.from_euler("z", deg, degrees=True).as_matrix()


def _gt_rmse(T: np.ndarray, T_true: np.ndarray, xyz: np.ndarray) -> float:
    d = apply_transform(T, xyz) - apply_transform(T_true, xyz)
    return float(np.sqrt(np.mean(np.sum(d**2, axis=1))))


def _matches(transforms: list[np.ndarray], residuals: list[float]) -> TetraMatches:
    n = len(transforms)
    idx = np.tile(np.arange(4), (n, 1))
    return TetraMatches(
        target_idx=idx,
        source_idx=idx,
        T_target_source=np.asarray(transforms),
        volume_m3=np.ones(n),
        edge_error=np.full(n, 0.01),
        svd_residual_m=np.asarray(residuals, dtype=float),
        n_target_tetra=10,
        n_source_tetra=10,
        n_descriptor_pairs=n,
    )


def _tiny_pair(tiny_tree):
    """Target: the tiny tree; source: the same points moved by a known transform.
    Writable copies: see test_read_only_inputs_are_accepted for the read-only case."""
    target = np.array(tiny_tree.xyz)
    T_true = make_transform(_rot_z(40.0), [2.0, -1.0, 0.2])
    return target, apply_transform(invert_transform(T_true), target), T_true


def test_right_transform_ranks_first_and_agreeing_matches_group(tiny_tree) -> None:
    """Two matches proposing (nearly) the same right transform and two wrong ones."""
    target, source, T_true = _tiny_pair(tiny_tree)
    nudge = make_transform(_rot_z(0.5), [0.03, 0.0, 0.0])
    again = make_transform(np.eye(3), [1e-4, 0.0, 0.0]) @ nudge
    wrong_a = make_transform(_rot_z(100.0), [2.0, -1.0, 0.2])
    wrong_b = make_transform(_rot_z(40.0), [2.0, 1.5, 3.0])
    m = _matches(
        [wrong_a, nudge @ T_true, wrong_b, again @ T_true], [0.01, 0.05, 0.02, 0.08]
    )
    ranked = rank_candidates(m, target, source, CoarseParams(polish_top=2))
    assert ranked.n_matches == 4
    assert len(ranked.candidates) == 3  # the two right matches are one solution
    best = ranked.candidates[0]
    assert best.support == 2
    assert [c.rank for c in ranked.candidates] == [1, 2, 3]
    assert best.score > 0.9
    assert all(c.score < 0.5 for c in ranked.candidates[1:])
    # The representative is the lower-residual member; the polish refines it.
    np.testing.assert_array_equal(best.T_match, nudge @ T_true)
    assert best.svd_residual_m == 0.05
    assert best.polished
    assert _gt_rmse(best.T_match, T_true, source) > 0.05
    assert _gt_rmse(best.T_target_source, T_true, source) < 0.02
    assert "2 tetrahedron match(es) agree" in best.explanation
    # Polished solutions come first, unpolished ones after.
    assert [c.polished for c in ranked.candidates] == [True, True, False]
    coarse = choose_coarse(ranked, centre=source.mean(axis=0))
    assert coarse.candidate is best
    np.testing.assert_array_equal(coarse.T_target_source, best.T_target_source)
    assert coarse.confidence > 0.5
    assert coarse.runner_up_score == pytest.approx(
        max(c.score for c in ranked.candidates[1:])
    )


def test_read_only_inputs_are_accepted(tiny_tree) -> None:
    target, source, T_true = _tiny_pair(tiny_tree)
    target.setflags(write=False)
    source.setflags(write=False)
    ranked = rank_candidates(_matches([T_true], [0.01]), target, source, CoarseParams())
    assert ranked.candidates[0].score > 0.9


def test_transforms_a_millimetre_apart_are_one_solution(tiny_tree) -> None:
    _, source, _ = _tiny_pair(tiny_tree)
    centre = source.mean(axis=0)
    cell = CoarseParams().same_solution_m
    k = np.round(centre[0] / cell)
    # Moved centre x = k*cell -/+ 0.5 mm: 1 mm apart, straddling a cell boundary.
    T1 = make_transform(np.eye(3), [k * cell - 0.0005 - centre[0], 0.0, 0.0])
    T2 = make_transform(np.eye(3), [k * cell + 0.0005 - centre[0], 0.0, 0.0])
    moved = [T @ np.r_[centre, 1.0] for T in (T1, T2)]
    assert np.linalg.norm(moved[0] - moved[1]) == pytest.approx(0.001)
    ranked = rank_candidates(
        _matches([T1, T2], [0.01, 0.02]),
        apply_transform(T1, source),
        source,
        CoarseParams(polish_top=0),
    )
    assert len(ranked.candidates) == 1
    assert ranked.candidates[0].support == 2


def test_no_match_gives_an_empty_list_and_a_clear_failure() -> None:
    empty = TetraMatches.empty()
    pts = np.random.default_rng(0).uniform(0, 1, (100, 3))
    ranked = rank_candidates(empty, pts, pts, CoarseParams())
    assert ranked == CandidateList((), 0)
    with pytest.raises(RegistrationFailed, match="No similar tetrahedra"):
        choose_coarse(ranked)


@pytest.fixture(scope="module")
def sample_candidates(sample_run) -> CandidateList:
    """The ranked list the default pipeline built for the sample pair
    (prepare_scan, skeletonise_scan, find_matches with default parameters)."""
    matches = sample_run.result.matches
    return CandidateList(matches.candidates, matches.n_matches)


def _local_gt_rmse(sample_pair, sample_run, T_local) -> float:
    from amrst.types import world_transform

    T = world_transform(T_local, sample_pair.target, sample_pair.source)
    return _gt_rmse(T, sample_pair.T_true, sample_pair.source.world_xyz)


def test_sample_top_candidate_is_near_the_truth(
    sample_pair, sample_run, sample_candidates
) -> None:
    cands = sample_candidates.candidates
    assert len(cands) >= 2
    assert [c.rank for c in cands] == list(range(1, len(cands) + 1))
    assert len({c.id for c in cands}) == len(cands)
    polished = [c.score for c in cands if c.polished]
    assert polished == sorted(polished, reverse=True)
    coarse = choose_coarse(sample_candidates)
    assert coarse.candidate.rank == 1
    assert _local_gt_rmse(sample_pair, sample_run, coarse.T_target_source) < 0.3
    assert 0.0 <= coarse.confidence <= 1.0
    assert coarse.message


def test_rejecting_the_top_candidate_returns_the_next(sample_candidates) -> None:
    cands = sample_candidates.candidates
    first = choose_coarse(sample_candidates)
    second = choose_coarse(sample_candidates, frozenset({first.candidate.id}))
    assert second.candidate.id != first.candidate.id
    assert second.candidate.rank == 2
    assert second.candidate is cands[1]
    assert len(cands) >= 3
    third = choose_coarse(sample_candidates, frozenset({cands[0].id, cands[1].id}))
    assert third.candidate is cands[2]


def test_rejecting_every_candidate_raises(sample_candidates) -> None:
    all_ids = frozenset(c.id for c in sample_candidates.candidates)
    with pytest.raises(RegistrationFailed, match="All candidate matches are rejected"):
        choose_coarse(sample_candidates, all_ids)
