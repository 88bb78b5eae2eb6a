"""The review of one target/source link: rejections, manual poses, the verdict.

Review decisions are data kept by pose, not by candidate id, so they survive every
re-run, preset and parameter change: a rejected pose stays rejected when
matching finds it again under a new id; a manual pose stays in the list and is scored
again with the new settings. A mixin of :class:`~amrst_gui.session.Session`; no Qt.
"""

from __future__ import annotations

import dataclasses
import logging
from typing import TYPE_CHECKING

import numpy as np

from amrst_gui.state import LinkId, LinkReview, ScanId

if TYPE_CHECKING:
    from amrst.params import RegistrationParams
    from amrst.pipeline import MatchResult, ScanAnalysis
    from amrst.review.verdict import Verdict
    from amrst.stages.candidates import Candidate, CoarseResult
    from amrst.stages.fine import FineResult

log = logging.getLogger("amrst_gui.session")


class ReviewMixin:
    """Review state of the links: rejected poses, manual candidates, accepted pose."""

    if TYPE_CHECKING:
        _matches: MatchResult | None
        _rejected: frozenset[int]
        _selected: int | None
        _accepted: CoarseResult | None
        _fine: FineResult | None
        _params: RegistrationParams
        _step_params: dict[str, RegistrationParams]
        _coarse_cache: tuple | None
        _roles: dict[str, ScanId]

        def analysis(self, role: str) -> ScanAnalysis | None: ...

        def _fail(self, message: str) -> None: ...

    def _reset_review(self) -> None:
        """Forget every review (new scans or swapped roles: other links)."""
        self._reviews: dict[LinkId, LinkReview] = {}
        self._combined: tuple[tuple, MatchResult | None] | None = None

    @property
    def _review(self) -> LinkReview:
        """The review of the current link (target scan, source scan)."""
        link = (self._roles["target"], self._roles["source"])
        return self._reviews.setdefault(link, LinkReview())

    # ------------------------------------------------------------ candidates
    @property
    def matches(self) -> tuple[Candidate, ...]:
        """Ranked candidates, manual poses first, then the automatic ones."""
        combined = self.match_result
        return () if combined is None else tuple(combined.candidates)

    @property
    def match_result(self) -> MatchResult | None:
        """The MatchResult with the manual candidates in front, or None."""
        key = (id(self._matches), self._review.manual)
        if self._combined is not None and self._combined[0] == key:
            return self._combined[1]
        value = self._combine()
        self._combined = (key, value)
        return value

    @property
    def manual_candidates(self) -> tuple[Candidate, ...]:
        """The manual candidates (origin "manual"), newest first."""
        return tuple(c for c in self.matches if c.origin == "manual")

    @property
    def manual_labels(self) -> dict[int, str]:
        """How each manual candidate was made ("3 point pairs", "typed", ...), by id."""
        return dict(self._review.manual_labels)

    def _combine(self) -> MatchResult | None:
        from amrst.pipeline import MatchResult
        from amrst.stages.match import TetraMatches

        auto = () if self._matches is None else tuple(self._matches.candidates)
        if not self._review.manual:
            return self._matches
        ranked = [
            dataclasses.replace(c, rank=i)
            for i, c in enumerate((*self._review.manual, *auto), start=1)
        ]
        if self._matches is not None:
            return dataclasses.replace(self._matches, candidates=tuple(ranked))
        source = self.analysis("source")
        centre = source.xyz.mean(axis=0) if source is not None else np.zeros(3)
        return MatchResult(TetraMatches.empty(), tuple(ranked), 0, {}, centre)

    @property
    def rejected(self) -> frozenset[int]:
        """Ids of the candidates the user rejected."""
        return self._rejected

    @property
    def selected_match(self) -> Candidate | None:
        """The Candidate shown in the views, or None."""
        return self._candidate(self._selected)

    @property
    def coarse(self) -> CoarseResult | None:
        """CoarseResult from the best candidate not rejected (None if none is left)."""
        return self._coarse_state()[0]

    @property
    def coarse_message(self) -> str:
        """Why the coarse solution is what it is (or why there is none)."""
        return self._coarse_state()[1]

    def _coarse_state(self) -> tuple[CoarseResult | None, str]:
        combined = self.match_result
        if combined is None:
            return None, "No matches yet: run Match."
        key = (id(combined), self._rejected)
        if self._coarse_cache is None or self._coarse_cache[0] != key:
            from amrst import pipeline
            from amrst.errors import RegistrationFailed

            value: tuple[CoarseResult | None, str]
            try:
                coarse = pipeline.coarse_from_matches(combined, self._rejected)
                value = (coarse, str(coarse.message))
            except RegistrationFailed as exc:
                value = (None, str(exc))
            self._coarse_cache = (key, value)
        return self._coarse_cache[1]

    def _candidate_ids(self) -> set[int]:
        return {int(c.id) for c in self.matches}

    def _candidate(self, match_id: int | None) -> Candidate | None:
        for c in self.matches:
            if c.id == match_id:
                return c
        return None

    def _describe_match(self, match_id: int) -> str:
        c = self._candidate(match_id)
        return f"#{c.rank} (id {c.id}, score {c.score:.0%})" if c else str(match_id)

    # ---------------------------------------------------------------- review
    def _remember_rejection(self, match_id: int) -> None:
        c = self._candidate(match_id)
        if c is not None:
            self._review.rejected_poses = (
                *self._review.rejected_poses,
                c.T_target_source,
            )

    def _forget_rejection(self, match_id: int) -> None:
        from amrst.stages.coarse import same_solution

        c = self._candidate(match_id)
        if c is None:
            return
        centre = self._centre()
        self._review.rejected_poses = tuple(
            T
            for T in self._review.rejected_poses
            if not same_solution(T, c.T_target_source, centre)
        )

    def _centre(self) -> np.ndarray:
        combined = self.match_result
        if combined is not None:
            return np.asarray(combined.source_centre)
        source = self.analysis("source")
        return source.xyz.mean(axis=0) if source is not None else np.zeros(3)

    def _carry_review(self) -> frozenset[int]:
        """Rejected ids of the new candidate list, found by pose; log what carried."""
        from amrst.stages.coarse import same_solution

        centre = self._centre()
        kept = frozenset(
            int(c.id)
            for c in self.matches
            if any(
                same_solution(c.T_target_source, T, centre)
                for T in self._review.rejected_poses
            )
        )
        notes = []
        if self._review.rejected_poses:
            notes.append(
                f"{len(kept)} candidate(s) start rejected because they are pose(s) you "
                f"rejected before ({len(self._review.rejected_poses)} rejected pose(s) kept)"
                + (
                    f": {', '.join(self._describe_match(i) for i in sorted(kept))}"
                    if kept
                    else ""
                )
            )
        if self._review.manual:
            notes.append(
                f"{len(self._review.manual)} manual pose(s) kept and scored again"
            )
        if self._review.accepted_pose is not None:
            same = next(
                (
                    c
                    for c in self.matches
                    if c.id not in kept
                    and same_solution(
                        c.T_target_source, self._review.accepted_pose, centre
                    )
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
    @property
    def verdict(self) -> Verdict | None:
        """The verdict of the current registration, or None before matching."""
        from amrst.review.verdict import judge

        if self.match_result is None:
            return None
        params = self._step_params.get("match") or self._params
        coarse = self._accepted if self._accepted is not None else self.coarse
        return judge(
            coarse,
            candidates=self.matches,
            no_coarse_message=self.coarse_message,
            fine=self._fine,
            tight_dist_m=params.coarse.tight_dist_m,
            score_dist_m=params.trunk.score_dist_m,
            trunk_searched=self._matches is not None
            and "trunk" in self._matches.timings,
        )

    def _next_manual_id(self) -> int:
        from amrst.review.manual import MANUAL_ID_BASE

        self._review.manual_next += 1
        return MANUAL_ID_BASE + self._review.manual_next
