"""The review of one target/source link: rejections, manual poses, the verdict.

Review decisions are data kept by pose, not by candidate id, so they survive every
re-run, preset and parameter change: a rejected pose stays rejected when
matching finds it again under a new id; a manual pose stays in the list and is scored
again with the new settings. The Session owns one :class:`Review`; no Qt.
"""

from __future__ import annotations

import dataclasses
import logging
from typing import TYPE_CHECKING, Any

import numpy as np

from amrst_gui.state import LinkId, LinkReview

if TYPE_CHECKING:
    from collections.abc import Callable

    from amrst.params import RegistrationParams
    from amrst.pipeline import MatchResult, ScanAnalysis
    from amrst.review.overlap import OverlapDistances
    from amrst.review.strength import Strength
    from amrst.review.verdict import Verdict
    from amrst.stages.candidates import Candidate, CoarseResult
    from amrst.stages.fine import FineResult

log = logging.getLogger("amrst_gui.session")

#: What each candidate source is called in a sentence.
SOURCE_TEXT = {
    "tetrahedra": "tetrahedron matches",
    "trunk": "trunk heading search",
    "manual": "your manual pose",
    "stems": "stem map",
}


class Review:
    """The candidates of the current link and the technician's decisions on them.

    Holds the last Match's result (``automatic``), the rejected candidate ids
    (``rejected``), the candidate shown (``selected``) and, per link, the review
    kept by pose (rejected poses, manual poses, the accepted pose).

    Parameters
    ----------
    link : callable
        Returns the current link, ``(target scan id, source scan id)``.
    source_analysis : callable
        Returns the source scan's ScanAnalysis, or None (for the centre that
        tells poses apart when there is no match result yet).
    """

    def __init__(
        self,
        link: Callable[[], LinkId],
        source_analysis: Callable[[], ScanAnalysis | None],
    ) -> None:
        self._link = link
        self._source_analysis = source_analysis
        self.reset()

    def reset(self) -> None:
        """Forget the candidates and every link's review (new scans, swapped roles)."""
        self.automatic: MatchResult | None = None
        self.rejected: frozenset[int] = frozenset()
        self.selected: int | None = None
        # The candidate the technician accepted by name (Accept coarse on a selected
        # row), taken before a better-ranked one until rejected or a new list.
        self.preferred: int | None = None
        self._reviews: dict[LinkId, LinkReview] = {}
        # Caches keyed on the objects they were made from, compared by identity:
        # the id() of an object no longer held can come back for a new one.
        self._combined: tuple[Any, Any, MatchResult | None] | None = None
        self._coarse_cache: (
            tuple[MatchResult, tuple[Any, Any], tuple[CoarseResult | None, str]] | None
        ) = None

    def clear_matches(self) -> None:
        """Forget the candidates (the match step's result is out of date)."""
        self.automatic, self.rejected, self.selected = None, frozenset(), None
        self.preferred = None

    @property
    def link_review(self) -> LinkReview:
        """The review of the current link (target scan, source scan)."""
        return self._reviews.setdefault(self._link(), LinkReview())

    # ------------------------------------------------------------ candidates
    @property
    def matches(self) -> tuple[Candidate, ...]:
        """Ranked candidates, manual poses first, then the automatic ones."""
        combined = self.match_result
        return () if combined is None else tuple(combined.candidates)

    @property
    def match_result(self) -> MatchResult | None:
        """The MatchResult with the manual candidates in front, or None."""
        auto, manual = self.automatic, self.link_review.manual
        if self._combined is not None:
            was_auto, was_manual, value = self._combined
            if was_auto is auto and was_manual is manual:
                return value
        value = self._combine()
        self._combined = (auto, manual, value)
        return value

    @property
    def manual_candidates(self) -> tuple[Candidate, ...]:
        """The manual candidates (origin "manual"), newest first."""
        return tuple(c for c in self.matches if c.origin == "manual")

    @property
    def manual_labels(self) -> dict[int, str]:
        """How each manual candidate was made ("3 point pairs", "typed", ...), by id."""
        return dict(self.link_review.manual_labels)

    def _combine(self) -> MatchResult | None:
        from amrst.pipeline import MatchResult
        from amrst.stages.match import TetraMatches

        review = self.link_review
        auto = () if self.automatic is None else tuple(self.automatic.candidates)
        if not review.manual:
            return self.automatic
        ranked = [
            dataclasses.replace(c, rank=i)
            for i, c in enumerate((*review.manual, *auto), start=1)
        ]
        if self.automatic is not None:
            return dataclasses.replace(self.automatic, candidates=tuple(ranked))
        source = self._source_analysis()
        centre = source.xyz.mean(axis=0) if source is not None else np.zeros(3)
        return MatchResult(TetraMatches.empty(), tuple(ranked), 0, {}, centre)

    @property
    def selected_match(self) -> Candidate | None:
        """The Candidate shown in the views, or None."""
        return self.candidate(self.selected)

    @property
    def coarse(self) -> CoarseResult | None:
        """CoarseResult from the preferred candidate, else the best not rejected
        (None if none is left)."""
        return self._coarse_state()[0]

    @property
    def coarse_message(self) -> str:
        """Why the coarse solution is what it is (or why there is none)."""
        return self._coarse_state()[1]

    def _coarse_state(self) -> tuple[CoarseResult | None, str]:
        combined = self.match_result
        if combined is None:
            return None, "No matches yet: run Match."
        key = (self.rejected, self.preferred)
        cached = self._coarse_cache
        if cached is None or cached[0] is not combined or cached[1] != key:
            from amrst import pipeline
            from amrst.errors import RegistrationFailed

            excluded = self.rejected
            if self.preferred is not None and self.preferred not in self.rejected:
                excluded = frozenset(self.candidate_ids() - {self.preferred})
            value: tuple[CoarseResult | None, str]
            try:
                coarse = pipeline.coarse_from_matches(combined, excluded)
                value = (coarse, str(coarse.message))
            except RegistrationFailed as exc:
                value = (None, str(exc))
            self._coarse_cache = cached = (combined, key, value)
        return cached[2]

    def candidate_ids(self) -> set[int]:
        """The ids of every candidate in the list."""
        return {int(c.id) for c in self.matches}

    def candidate(self, match_id: int | None) -> Candidate | None:
        """The candidate with ``match_id``, or None."""
        for c in self.matches:
            if c.id == match_id:
                return c
        return None

    def describe(self, match_id: int) -> str:
        """``#rank (id, score)`` of a candidate, for the log."""
        c = self.candidate(match_id)
        return f"#{c.rank} (id {c.id}, score {c.score:.0%})" if c else str(match_id)

    # ---------------------------------------------------------------- review
    def reject(self, match_id: int) -> None:
        """Reject a candidate, and its pose for every later candidate list."""
        self.rejected = self.rejected | {match_id}
        c = self.candidate(match_id)
        if c is not None:
            review = self.link_review
            review.rejected_poses = (*review.rejected_poses, c.T_target_source)

    def restore(self, match_id: int) -> None:
        """Undo the rejection of a candidate and of its pose."""
        from amrst.stages.coarse import same_solution

        c = self.candidate(match_id)
        if c is not None:
            centre = self.centre()
            review = self.link_review
            review.rejected_poses = tuple(
                T
                for T in review.rejected_poses
                if not same_solution(T, c.T_target_source, centre)
            )
        self.rejected = self.rejected - {match_id}

    def centre(self) -> np.ndarray:
        """The source centre that tells two poses apart (``same_solution``)."""
        combined = self.match_result
        if combined is not None:
            return np.asarray(combined.source_centre)
        source = self._source_analysis()
        return source.xyz.mean(axis=0) if source is not None else np.zeros(3)

    def set_matches(self, automatic: MatchResult, manual: tuple) -> None:
        """A new Match result and the manual poses scored again: the rejected
        poses carry over to the new ids, and so does the candidate chosen, by its
        pose (else the best candidate left is shown)."""
        from amrst.stages.coarse import same_solution

        chosen = self.candidate(self.preferred)
        self.automatic = automatic
        self.link_review.manual = manual
        self.rejected = self._carry()
        self.preferred = None
        left = [c for c in self.matches if c.id not in self.rejected]
        if chosen is not None:
            centre = self.centre()
            same = [
                c
                for c in left
                if same_solution(c.T_target_source, chosen.T_target_source, centre)
            ]
            if same:
                self.preferred = int(same[0].id)
            else:
                log.info(
                    "The candidate you chose is not among the new matches; the best "
                    "one left is taken."
                )
        self.selected = (
            self.preferred
            if self.preferred is not None
            else (left[0].id if left else None)
        )

    def add_manual(self, candidate: Candidate) -> None:
        """A scored manual pose goes first in the list, shown and not rejected."""
        review = self.link_review
        review.manual = (candidate, *review.manual)
        self.rejected = self.rejected - {int(candidate.id)}
        self.selected = int(candidate.id)
        self.preferred = None

    def _carry(self) -> frozenset[int]:
        """Rejected ids of the new candidate list, found by pose; log what carried."""
        from amrst.stages.coarse import same_solution

        centre = self.centre()
        review = self.link_review
        kept = frozenset(
            int(c.id)
            for c in self.matches
            if any(
                same_solution(c.T_target_source, T, centre)
                for T in review.rejected_poses
            )
        )
        notes = []
        if review.rejected_poses:
            notes.append(
                f"{len(kept)} candidate(s) start rejected because they are pose(s) you "
                f"rejected before ({len(review.rejected_poses)} rejected pose(s) kept)"
                + (
                    f": {', '.join(self.describe(i) for i in sorted(kept))}"
                    if kept
                    else ""
                )
            )
        if review.manual:
            notes.append(f"{len(review.manual)} manual pose(s) kept and scored again")
        if review.accepted_pose is not None:
            same = next(
                (
                    c
                    for c in self.matches
                    if c.id not in kept
                    and same_solution(c.T_target_source, review.accepted_pose, centre)
                ),
                None,
            )
            notes.append(
                f"the pose you accepted before is candidate #{same.rank}"
                if same is not None
                else "the pose you accepted before is not among the new candidates"
            )
        if notes:
            log.info("Review carried over: %s.", "; ".join(notes))
        return kept

    # --------------------------------------------------------------- verdict
    def verdict(
        self,
        accepted: CoarseResult | None,
        fine: FineResult | None,
        params: RegistrationParams,
        overlap: OverlapDistances | None = None,
        strength: Strength | None = None,
        *,
        as_shown: bool = True,
    ) -> Verdict | None:
        """The verdict of the registration (``accepted`` coarse, else the coarse
        solution of the list, then ``fine``), or None before matching.
        ``params``: those the match step ran with; ``overlap`` and ``strength``: the
        final pose's (a manual pose, or an unverified candidate the technician
        accepted, is judged by them; weak axes are named).

        Once the accepted candidate is rejected or another one ranks above it, the
        result no longer stands: the verdict shown (``as_shown``) says what Accept
        coarse would take instead (*needs review*), or the list's own when every
        candidate is rejected. ``as_shown=False`` judges the result itself (is it
        worth keeping?).
        """
        from amrst.review.verdict import judge

        if self.match_result is None:
            return None
        now = self.coarse
        if (
            as_shown
            and accepted is not None
            and (now is None or now.candidate.id != accepted.candidate.id)
        ):
            return self._superseded(accepted, now, params)
        coarse = accepted if accepted is not None else now
        return judge(
            coarse,
            candidates=self.matches,
            no_coarse_message=self.coarse_message,
            fine=fine,
            tight_dist_m=params.coarse.tight_dist_m,
            score_dist_m=params.trunk.score_dist_m,
            trunk_searched=self.automatic is not None
            and "trunk" in self.automatic.timings,
            overlap=overlap,
            strength=strength,
            accepted_by_hand=accepted is not None and not accepted.verified,
        )

    def _superseded(
        self,
        accepted: CoarseResult,
        now: CoarseResult | None,
        params: RegistrationParams,
    ) -> Verdict | None:
        """The verdict of a result whose candidate is no longer the coarse solution."""
        from amrst.review.verdict import NEEDS_REVIEW, Verdict

        if now is None:  # every candidate rejected: the list's own verdict
            return self.verdict(None, None, params)
        old = accepted.candidate.id
        was = next((c for c in self.matches if c.id == old), None)
        why = (
            "which you rejected"
            if old in self.rejected
            else "which is no longer the best candidate"
        )
        best = now.candidate
        source = SOURCE_TEXT.get(str(best.origin), "matching")
        return Verdict(
            NEEDS_REVIEW,
            f"The result shown comes from candidate "
            f"{'#' + str(was.rank) if was is not None else old}, {why}. Accept coarse "
            f"now takes candidate #{best.rank} ({source}, score {best.score:.0%}).",
            "Look at it in the views, then Accept coarse (Ctrl+4).",
        )

    def next_manual_id(self) -> int:
        """A new id for a manual candidate of this link."""
        from amrst.review.manual import MANUAL_ID_BASE

        review = self.link_review
        review.manual_next += 1
        return MANUAL_ID_BASE + review.manual_next
