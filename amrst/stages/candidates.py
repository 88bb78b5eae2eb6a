"""Candidate solutions: where each came from, how it verified, and which are the same.

Every source of candidates (tetrahedron matches, the trunk heading search, a generic
feature matcher, the user's own pairs) produces ``Candidate`` rows of one ranked
``CandidateList``; ``CoarseResult`` is the one chosen.
"""

from __future__ import annotations

from dataclasses import dataclass
from enum import Enum

import numpy as np

from amrst.errors import RegistrationFailed
from amrst.types import Transform, rotation_angle_deg

# Two solutions are different when they move the tree centre more than DISTINCT_M apart
# or differ by more than DISTINCT_DEG of rotation (see distinct_solutions).
DISTINCT_M = 0.5
DISTINCT_DEG = 5.0
SCORE_FULL_CREDIT = 0.3
# Below this polished score no candidate counts as verified: it lies between what right
# and wrong winners of the benchmark cases score after the polish.
MIN_VERIFIED_SCORE = 0.15
# Trunk solutions: verified also when this share lands within the tight distance and the
# next heading scores at most half as much (docs/how-it-works.md, trunk heading search).
MIN_PRECISE_SCORE = 0.03
MIN_SEPARATION = 0.5


class Origin(str, Enum):
    """Where a candidate solution came from (compares equal to its value)."""

    TETRAHEDRA = "tetrahedra"  # a similar-tetrahedra match (the paper's method)
    TRUNK = "trunk"  # the trunk-anchored heading search (levelled scans)
    FEATURES = "features"  # a generic feature matcher (e.g. KISS-Matcher)
    MANUAL = "manual"  # given by the user: point pairs, nudge or a typed transform
    STEMS = "stems"  # a plot's stem map: stem bases and DBH of both scans

    def __str__(self) -> str:
        return self.value


@dataclass(frozen=True, slots=True)
class Candidate:
    """One candidate solution: a tetrahedron match, its transform and how well it verified."""

    id: int
    rank: int  # 1 = best
    score: float  # verification score 0..1 (after the polish where polished)
    raw_score: float  # overlap under the tetrahedron transform itself
    support: int  # tetrahedron matches agreeing with this solution
    volume_m3: float
    edge_error: float  # largest relative edge difference of the tetrahedron pair
    svd_residual_m: float  # RMS vertex distance after the Kabsch fit
    target_idx: np.ndarray  # (4,) target key point indices
    source_idx: (
        np.ndarray
    )  # (4,) source key point indices, vertex i <-> target vertex i
    T_match: Transform  # Kabsch transform of the tetrahedron pair
    T_target_source: Transform  # T_match, polished when it was among the best
    polished: bool
    explanation: str
    origin: Origin = Origin.TETRAHEDRA
    # Trunk solutions only: share of points within trunk.score_dist_m after the fine
    # fit, and the point set that fit used ("" = fine.points).
    precise_score: float = float("nan")
    fine_points: str = ""
    # Other sources that proposed the same solution (one candidate names them all).
    also_found_by: tuple[Origin, ...] = ()

    @property
    def origins(self) -> tuple[Origin, ...]:
        """Every source that proposed this solution, its own origin first."""
        return (self.origin, *self.also_found_by)


@dataclass(frozen=True, slots=True)
class CandidateList:
    """All solutions, best first."""

    candidates: tuple[Candidate, ...]
    n_matches: int  # tetrahedron matches before grouping


@dataclass(frozen=True, slots=True)
class CoarseResult:
    """The chosen coarse solution."""

    candidate: Candidate
    T_target_source: Transform
    confidence: float  # 0..1: 1 - runner-up score / winner score (different solutions)
    runner_up_score: float
    message: str
    verified: bool  # polished and scoring >= MIN_VERIFIED_SCORE: safe to use unattended


def distinct_solutions(a: Transform, b: Transform, centre: np.ndarray) -> bool:
    """Tell whether two transforms are different solutions (the inverse of same_solution).

    Different when they move ``centre`` more than ``DISTINCT_M`` apart or differ by more
    than ``DISTINCT_DEG`` of rotation. This is the one test behind the confidence
    (rivals), the trunk search's kept headings and the rejections carried over to a
    new match; ``CoarseParams.same_solution_m/_deg`` is a different, tighter notion:
    which tetrahedron matches are grouped into one candidate.
    """
    d = np.linalg.norm((a[:3, :3] - b[:3, :3]) @ centre + a[:3, 3] - b[:3, 3])
    return bool(
        d > DISTINCT_M or rotation_angle_deg(a[:3, :3] @ b[:3, :3].T) > DISTINCT_DEG
    )


def same_solution(a: Transform, b: Transform, centre: np.ndarray) -> bool:
    """Tell whether two transforms are one solution, as the confidence counts them.

    Parameters
    ----------
    a, b : (4, 4) float64
        Two T_target_source.
    centre : (3,) float64
        Source point the transforms are compared at (the tree centre).

    Returns
    -------
    bool
        True when they move ``centre`` less than 0.5 m apart and differ by at most
        5 deg of rotation.
    """
    return not distinct_solutions(a, b, centre)


def choose_coarse(
    candidates: CandidateList,
    rejected: frozenset[int] = frozenset(),
    centre: np.ndarray | None = None,
) -> CoarseResult:
    """Return the best candidate the user has not rejected, with a confidence.

    Parameters
    ----------
    candidates : CandidateList
    rejected : frozenset of int
        Candidate ids the user rejected.
    centre : (3,) float64 or None
        Source point around which transforms are compared (default: origin).

    Returns
    -------
    CoarseResult

    Raises
    ------
    RegistrationFailed
        When no candidate is left.
    """
    left = [c for c in candidates.candidates if c.id not in rejected]
    if not left:
        if candidates.candidates:
            raise RegistrationFailed(
                "All candidate matches are rejected: restore one, or change the matching parameters and match again."
            )
        raise RegistrationFailed(
            "No similar tetrahedra were found between the two skeletons. Try a larger edge tolerance ε, "
            "a larger SVD residual δ, more key points (depth rule), or check that both files show the same tree."
        )
    best = left[0]
    centre = np.zeros(3) if centre is None else centre
    # Scores are comparable only between candidates verified the same way: trunk
    # solutions (refined, then scored tightly) among themselves, polished tetrahedron
    # solutions among themselves.
    rivals = [
        c
        for c in left[1:]
        if (c.origin is Origin.TRUNK) == (best.origin is Origin.TRUNK)
        and c.polished == best.polished
        and distinct_solutions(c.T_target_source, best.T_target_source, centre)
    ]
    if best.origin is Origin.TRUNK:
        key = best.precise_score
        runner_key = max((c.precise_score for c in rivals), default=0.0)
    else:
        key = best.score
        runner_key = max((c.score for c in rivals), default=0.0)
    runner = max((c.score for c in rivals), default=0.0)
    # Confidence: how clearly the winner beats a different solution, times how well it
    # fits at all (full credit from SCORE_FULL_CREDIT, a score wrong winners do not reach).
    separation = float(np.clip(1 - runner_key / key, 0, 1)) if key > 0 else 0.0
    if best.origin is Origin.TRUNK:
        fit = min(1.0, best.precise_score / (2 * MIN_PRECISE_SCORE))
    else:
        fit = min(1.0, best.score / SCORE_FULL_CREDIT)
    conf = separation * fit
    if best.origin is Origin.TRUNK:
        # Trunk solutions had a fine registration, so even a wrong heading scores
        # 0.2-0.3 at 4 cm: only the tight score and a clear lead verify one. The lead
        # needs something to lead: a distinct rival heading, or other headings that
        # converged to the same pose (a single kept heading verifies nothing).
        agree = sum(
            c.origin is Origin.TRUNK
            and not distinct_solutions(c.T_target_source, best.T_target_source, centre)
            for c in left[1:]
        )
        verified = bool(
            (rivals or agree)
            and best.precise_score >= MIN_PRECISE_SCORE
            and separation >= MIN_SEPARATION
        )
    else:
        verified = bool(best.polished and best.score >= MIN_VERIFIED_SCORE)
    if best.origin is Origin.TRUNK and verified:
        msg = (
            f"Candidate {best.rank} (trunk heading search): {best.precise_score:.0%} of the sampled source points "
            f"lie on the target, against {runner_key:.0%} for the next heading. The scans share little beyond the "
            "trunk; check the overlay by eye."
        )
    elif best.score < 0.1:
        msg = (
            f"Low confidence: only {best.score:.0%} of the sampled source points lie near the target. Check the matches by eye; "
            "the scans may overlap little or the skeletons may differ."
        )
    elif conf < 0.15:
        msg = (
            f"Low confidence: the runner-up solution scores almost as well ({runner:.0%} vs {best.score:.0%}). "
            "Review the top matches."
        )
    else:
        msg = f"Candidate {best.rank}: score {best.score:.0%}, confidence {conf:.0%}."
    return CoarseResult(best, best.T_target_source, conf, runner, msg, verified)


def wants_more(ranked: CandidateList, mode: str, centre: np.ndarray) -> bool:
    """Tell whether a candidate source should run, by its mode.

    "off": never; "always": always; otherwise ("fallback"): when the list is empty or
    its best candidate does not verify. The one rule of every extra source.
    """
    if mode == "off":
        return False
    if mode == "always" or not ranked.candidates:
        return True
    return not choose_coarse(ranked, frozenset(), centre).verified
