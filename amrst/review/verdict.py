"""One verdict per registration: registered, needs review, or failed.

The command line, the app's status bar, Matches header and Metrics dock, the exported
files and the report all say the same words, because they all call :func:`judge`.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from collections.abc import Sequence

    from amrst.review.overlap import OverlapDistances
    from amrst.review.strength import Strength
    from amrst.stages.coarse import Candidate, CoarseResult
    from amrst.stages.fine import FineResult

REGISTERED = "registered"
NEEDS_REVIEW = "needs review"
FAILED = "failed"
STATUSES = (REGISTERED, NEEDS_REVIEW, FAILED)
#: A verdict's text colour, in the reports and the app: dark enough to read on white.
TEXT_RGB = {REGISTERED: "#1b6e20", NEEDS_REVIEW: "#9a6200", FAILED: "#c00000"}

# Below this confidence a verified winner still needs a look (the runner-up is close).
LOW_CONFIDENCE = 0.3

# A manual pose stands on its own evidence when, where both scans saw the scene, the
# median distance is at most this, this share lies within 2 cm, on this many points,
# and no axis is weak: what a right pose of two field scans shows.
MANUAL_MEDIAN_M = 0.015
MANUAL_WITHIN_2CM = 0.5
MANUAL_MIN_POINTS = 200

# The way out when no candidate verifies, for the CLI and the app alike.
RECOVER = (
    "Check that both scans show the same tree; review the candidates in amrst-gui's "
    "Matches dock or recover the pose by hand there (point pairs, nudge, or a typed "
    'transform); or try the preset "Leaf-on broadleaf" or a larger edge tolerance.'
)


@dataclass(frozen=True, slots=True)
class Verdict:
    """What a technician must know about one registration.

    Attributes
    ----------
    status : str
        ``"registered"``, ``"needs review"`` or ``"failed"``.
    reason : str
        Why, in plain words, with the numbers that decided it.
    next_step : str
        What to do next.
    """

    status: str
    reason: str
    next_step: str

    @property
    def ok(self) -> bool:
        """True only for *registered*: safe to use without a second look."""
        return self.status == REGISTERED

    @property
    def headline(self) -> str:
        """``Registered``, ``Needs review`` or ``Failed``."""
        return self.status[0].upper() + self.status[1:]

    def text(self) -> str:
        """One paragraph: headline, reason, next step."""
        return f"{self.headline}: {self.reason} Next: {self.next_step}"

    def as_dict(self) -> dict[str, str]:
        """JSON-ready form, for the exported files."""
        return {
            "status": self.status,
            "reason": self.reason,
            "next_step": self.next_step,
        }


def _why_unverified(
    best: Candidate,
    runner_up_score: float,
    tight_dist_m: float,
    score_dist_m: float,
    trunk_searched: bool,
) -> str:
    """Say why a candidate did not verify (the words the CLI has always printed)."""
    if best.origin == "trunk":
        versus = (
            f"against {runner_up_score:.0%} within {tight_dist_m * 100:.0f} cm "
            "for the next heading, which is not a clear lead"
            if runner_up_score > 0
            else "with no other heading to compare it with"
        )
        return (
            f"The best solution comes from the trunk heading search: "
            f"{best.precise_score:.0%} of the sampled source points lie within "
            f"{score_dist_m * 100:.1f} cm of the target, {versus} (a round or "
            "symmetric stem, or scans that share little, fit several headings "
            "equally well)."
        )
    from amrst.stages.candidates import MIN_VERIFIED_SCORE

    return (
        f"The best solution puts only {best.score:.0%} of the sampled source points "
        f"within {tight_dist_m * 100:.0f} cm of the target (a solution verifies from "
        f"{MIN_VERIFIED_SCORE:.0%}, and a right one on scans that share most of the "
        "tree puts 45% or more there)"
        + (
            ", and the trunk heading search found no heading that clearly beats the "
            "others."
            if trunk_searched
            else "."
        )
    )


def _source(candidate: Candidate) -> str:
    """Name the source of a candidate, as the reason says it."""
    return {
        "manual": "your manual pose",
        "trunk": "the trunk heading search",
        "features": "the feature matcher",
        "stems": "the stem map",
    }.get(str(candidate.origin), "the tetrahedron matches")


def manual_verdict(
    overlap: OverlapDistances | None,
    strength: Strength | None,
    pose: str = "Your manual pose",
) -> Verdict:
    """Judge the technician's own pose by what it shows, not by a benchmark share.

    ``pose`` names it in the reason.
    """
    if overlap is None or overlap.n_points_measured == 0:
        return Verdict(
            NEEDS_REVIEW,
            f"{pose} leaves no part of the tree seen by both scans, so nothing "
            "confirms it.",
            "Check the overlay and the stem slices; refine the point pairs.",
        )
    seen = (
        f"{pose}: where both scans saw the scene ({overlap.n_points_measured} "
        f"points), the median distance is {overlap.median_m * 100:.1f} cm and "
        f"{overlap.within_2cm_fraction:.0%} lie within 2 cm."
    )
    weak = strength.advice() if strength is not None else ""
    # What a right pose shows and this one does not, named so that the figures
    # quoted are not read as evidence.
    short = [
        text
        for failed, text in (
            (
                not overlap.median_m <= MANUAL_MEDIAN_M,
                f"a median under {MANUAL_MEDIAN_M * 100:.1f} cm",
            ),
            (
                not overlap.within_2cm_fraction >= MANUAL_WITHIN_2CM,
                f"{MANUAL_WITHIN_2CM:.0%} or more within 2 cm",
            ),
            (
                overlap.n_points_measured < MANUAL_MIN_POINTS,
                f"{MANUAL_MIN_POINTS} or more points seen by both",
            ),
        )
        if failed
    ]
    if not short and not weak:
        return Verdict(
            REGISTERED,
            seen,
            "Look at the stem slices once, then export.",
        )
    unconfirmed = f"A right pose shows {', '.join(short)}." if short else ""
    return Verdict(
        NEEDS_REVIEW,
        " ".join(part for part in (seen, unconfirmed, weak) if part),
        "Check the overlay, the distance colours and the stem slices; run Fine "
        "registration and look again, or refine the point pairs.",
    )


def judge(
    coarse: CoarseResult | None,
    *,
    candidates: Sequence[Candidate] = (),
    no_coarse_message: str = "",
    fine: FineResult | None = None,
    tight_dist_m: float = 0.04,
    score_dist_m: float = 0.015,
    trunk_searched: bool = False,
    overlap: OverlapDistances | None = None,
    strength: Strength | None = None,
    accepted_by_hand: bool = False,
) -> Verdict:
    """Judge a registration from its coarse choice and (optionally) its fine result.

    Parameters
    ----------
    coarse : CoarseResult or None
        The chosen coarse solution; None when no candidate is left.
    candidates : sequence of Candidate
        Every candidate (to tell "none found" from "all rejected").
    no_coarse_message : str
        Why there is no coarse solution (shown when ``coarse`` is None).
    fine : FineResult or None
        The fine registration, when it ran.
    tight_dist_m, score_dist_m : float
        Distances of the verification scores (coarse.tight_dist_m,
        trunk.score_dist_m), named in the reason.
    trunk_searched : bool
        Whether the trunk heading search ran.
    overlap, strength : OverlapDistances, Strength or None
        The final pose's distances where both scans saw the scene and its strength
        per axis: a manual pose is judged by them, and a weak axis is named.
    accepted_by_hand : bool
        Whether the technician accepted ``coarse`` though it does not verify: it is
        then judged by its evidence, as a manual pose is, not failed.

    Returns
    -------
    Verdict
    """
    if coarse is None:
        if candidates:
            return Verdict(
                FAILED,
                "Every candidate is rejected, so there is no pose to use.",
                "Restore a candidate, or recover the pose by hand (point pairs, "
                "nudge, or a typed transform).",
            )
        return Verdict(
            FAILED,
            no_coarse_message or "Matching found no candidate.",
            RECOVER,
        )
    best = coarse.candidate
    if not coarse.verified:
        if best.origin == "manual":
            return manual_verdict(overlap, strength)
        if accepted_by_hand:
            return manual_verdict(
                overlap,
                strength,
                f"Candidate {best.rank} from {_source(best)}, which you accepted "
                "though it does not verify",
            )
        why = _why_unverified(
            best, coarse.runner_up_score, tight_dist_m, score_dist_m, trunk_searched
        )
        return Verdict(FAILED, f"No candidate verifies. {why}", RECOVER)
    if fine is not None and not fine.converged:
        return Verdict(
            NEEDS_REVIEW,
            f"Fine registration did not converge after {fine.iterations} iterations.",
            "Check the overlay; reject the candidate or try other fine parameters.",
        )
    if coarse.confidence < LOW_CONFIDENCE:
        return Verdict(
            NEEDS_REVIEW,
            f"Low confidence ({coarse.confidence:.0%}): {coarse.message}",
            "Compare the top candidates in the overlay and reject the wrong ones.",
        )
    source = _source(best)
    reason = (
        f"Candidate {best.rank} from {source} verifies: {best.score:.0%} of the "
        f"sampled source points lie within {tight_dist_m * 100:.0f} cm of the target, "
        f"confidence {coarse.confidence:.0%}."
    )
    weak = strength.advice() if strength is not None else ""
    if weak:
        nxt = weak
    elif fine is not None:
        nxt = "Nothing more is needed; a look at the stem slices confirms it."
    else:
        nxt = "Run Fine registration, then export."
    return Verdict(REGISTERED, reason, nxt)


def scans_status(verified: Sequence[bool], confidence: float) -> str:
    """Return the state of scans registered together, in the words of :func:`judge`.

    ``verified[k]`` tells whether scan k reaches the reference through links whose
    candidate verified (the reference itself counts); ``confidence`` is the weakest
    such link's. Every scan reached: registered, or needs review below
    ``LOW_CONFIDENCE`` as for a pair; some: needs review (the others are recovered by
    hand); none but the reference: failed. One link is ``[True, link verified]``.
    """
    n = sum(bool(v) for v in verified)
    if n == len(verified):
        return REGISTERED if confidence >= LOW_CONFIDENCE else NEEDS_REVIEW
    return NEEDS_REVIEW if n > 1 else FAILED


def judge_result(result: Any, params: Any) -> Verdict:
    """Judge a finished ``amrst.pipeline.RegistrationResult``.

    Parameters
    ----------
    result : RegistrationResult
    params : RegistrationParams

    Returns
    -------
    Verdict
    """
    return judge(
        result.coarse,
        candidates=result.matches.candidates,
        fine=result.fine,
        tight_dist_m=params.coarse.tight_dist_m,
        score_dist_m=params.trunk.score_dist_m,
        trunk_searched="trunk" in result.timings,
        overlap=getattr(result, "overlap", None),
        strength=getattr(result, "strength", None),
    )
