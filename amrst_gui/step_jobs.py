"""The app's code for each step of the step table, one block per step.

For a step called ``name`` (``amrst.pipeline.steps.STEPS``, plus the app's own jobs
``load``, ``manual`` and ``export``) the Session calls, by name:

- ``_start_<name>()``: launch its job (``self._launch``); may refuse
  (``self.runner.stop()``);
- ``_apply_<name>(result)``: store the result on the GUI thread, return the function
  that emits the step's signal;
- ``_done_<name>()``: does its result exist (engine steps);
- ``_summary_<name>()``: one line about the result, for the log;
- ``_clear_<name>()``: drop its result when an earlier step ran again.

Adding a step: one entry in the step table, one block here.
``tests/gui/test_step_table.py`` checks that every step has its four methods. A
mixin of the Session; no Qt.
"""

from __future__ import annotations

import functools
import logging
from typing import TYPE_CHECKING, Any

import numpy as np

from amrst_gui import jobs

if TYPE_CHECKING:
    from collections.abc import Callable
    from pathlib import Path

    from amrst.params import RegistrationParams
    from amrst.pipeline import MatchResult, ScanAnalysis
    from amrst.review.verdict import Verdict
    from amrst.stages.candidates import Candidate, CoarseResult
    from amrst.stages.fine import FineResult
    from amrst.stages.metrics import CloudMetrics
    from amrst.types import Cloud
    from amrst_gui.review import Review
    from amrst_gui.runner import StepRunner

log = logging.getLogger("amrst_gui.session")


class StepJobsMixin:
    """Start, apply, done and summary of each step (a mixin of the Session)."""

    if TYPE_CHECKING:
        _params: RegistrationParams
        _job_params: RegistrationParams
        _matches: MatchResult | None
        _rejected: frozenset[int]
        _selected: int | None
        _accepted: CoarseResult | None
        _fine: FineResult | None
        _fine_note: str
        _metrics: dict[str, CloudMetrics]
        _tree: dict[str, dict]
        _step_params: dict[str, RegistrationParams]
        runner: StepRunner
        _stop_unverified: bool
        _pending_manual: tuple[np.ndarray, str] | None
        _pending_paths: dict[str, Path]
        _exported_result: CoarseResult | FineResult | None
        _last_report: Path | None
        review: Review
        separation_finished: Any
        skeletons_finished: Any
        matches_changed: Any
        coarse_accepted: Any
        fine_finished: Any
        exported: Any
        scan_loaded: Any

        def _launch(self, step: str, fn: Callable, *args: Any) -> None: ...
        def _fail(self, message: str) -> None: ...
        def _clear_after(self, step: str) -> None: ...
        def _set_loaded(self, clouds: dict[str, Cloud]) -> None: ...
        def _by_role(self, what: str) -> dict[str, Any]: ...
        def _set_analyses(self, analyses: dict[str, ScanAnalysis]) -> None: ...
        def analysis(self, role: str) -> ScanAnalysis | None: ...
        def _name(self, role: str) -> str: ...
        def cloud(self, role: str) -> Cloud | None: ...
        @property
        def matches(self) -> tuple[Candidate, ...]: ...
        @property
        def coarse(self) -> CoarseResult | None: ...
        @property
        def coarse_message(self) -> str: ...
        @property
        def verdict(self) -> Verdict | None: ...

    # ------------------------------------------------------------------ load
    def _apply_load(self, result: dict[str, Cloud]) -> Callable[[], None]:
        self._set_loaded(result)
        roles = list(result)

        def emit_loaded() -> None:
            for r in roles:
                self.scan_loaded.emit(r)

        return emit_loaded

    def _summary_load(self) -> str:
        return "; ".join(
            f"{r}: {self._name(r)} ({len(c):,} points)"
            for r, c in self._by_role("cloud").items()
            if c is not None
        )

    # -------------------------------------------------------------- separate
    def _start_separate(self) -> None:
        self._launch(
            "separate", jobs.separate_pair, self._by_role("cloud"), self._params
        )

    def _apply_separate(self, result: dict[str, ScanAnalysis]) -> Callable[[], None]:
        self._set_analyses(result)
        return self.separation_finished.emit

    def _done_separate(self) -> bool:
        return self.analysis("target") is not None

    def _clear_separate(self) -> None:
        """Nothing: the analyses are replaced by the separate/skeleton result."""

    def _summary_separate(self) -> str:
        return "; ".join(
            f"{r}: {int(np.count_nonzero(a.is_wood)):,} wood "
            f"of {len(a.is_wood):,} points"
            for r, a in self._by_role("analysis").items()
        )

    # -------------------------------------------------------------- skeleton
    def _start_skeleton(self) -> None:
        self._launch(
            "skeleton", jobs.skeletonise_pair, self._by_role("analysis"), self._params
        )

    def _apply_skeleton(self, result: dict[str, ScanAnalysis]) -> Callable[[], None]:
        self._set_analyses(result)
        return self.skeletons_finished.emit

    def _done_skeleton(self) -> bool:
        an = self.analysis("target")
        return an is not None and an.keypoints is not None

    def _clear_skeleton(self) -> None:
        """Nothing: the analyses are replaced by the skeleton result."""

    def _summary_skeleton(self) -> str:
        return "; ".join(
            f"{r}: {len(a.skeleton.nodes)} skeleton nodes, "
            f"{len(a.keypoints.xyz)} key points"
            for r, a in self._by_role("analysis").items()
        )

    # ----------------------------------------------------------------- match
    def _start_match(self) -> None:
        labels = self.review.link_review.manual_labels
        manual = tuple(
            (c.T_match, int(c.id), labels.get(int(c.id), ""))
            for c in self.review.link_review.manual
        )
        match = functools.partial(jobs.match_pair, manual=manual)
        self._launch("match", match, self._by_role("analysis"), self._params)

    def _apply_match(self, result: tuple) -> Callable[[], None]:
        self.review.set_matches(*result)
        return self.matches_changed.emit

    def _done_match(self) -> bool:
        return self.review.automatic is not None

    def _clear_match(self) -> None:
        self.review.clear_matches()

    def _summary_match(self) -> str:
        return f"{len(self.matches)} candidates. {self.coarse_message}"

    # ---------------------------------------------------------------- manual
    def _start_manual(self) -> None:
        assert self._pending_manual is not None  # set by add_manual_pose
        T, how = self._pending_manual
        cid = self.review.next_manual_id()
        self.review.link_review.manual_labels[cid] = how
        an = self._by_role("analysis")
        self._launch("manual", jobs.score_manual_pair, an, T, cid, how, self._params)

    def _apply_manual(self, result: Candidate) -> Callable[[], None]:
        self.review.add_manual(result)
        log.info("Manual pose added: %s", result.explanation)
        return self.matches_changed.emit

    def _summary_manual(self) -> str:
        return ""

    # ---------------------------------------------------------------- coarse
    def _start_coarse(self) -> None:
        coarse = self.coarse
        if coarse is None:
            self.runner.stop()
            self._fail(f"No coarse solution to accept: {self.coarse_message}")
            return
        if self._stop_unverified and not coarse.verified:
            self.runner.stop()
            verdict = self.verdict
            self._fail(
                "Run all stopped before accepting an unverified candidate. "
                + (verdict.text() if verdict is not None else coarse.message)
            )
            return
        an = self._by_role("analysis")
        self._launch("coarse", jobs.evaluate_coarse, an, coarse, self._params)

    def _apply_coarse(self, result: tuple) -> Callable[[], None]:
        self._accepted, self._metrics["coarse"], self._tree["coarse"] = result
        accepted = self._accepted
        assert accepted is not None
        self.review.link_review.accepted_pose = accepted.T_target_source
        return lambda: self.coarse_accepted.emit(accepted)

    def _done_coarse(self) -> bool:
        return self._accepted is not None

    def _clear_coarse(self) -> None:
        self._accepted = None
        self._metrics.pop("coarse", None)
        self._tree.pop("coarse", None)

    def _summary_coarse(self) -> str:
        return self._metrics_line("coarse")

    # ------------------------------------------------------------------ fine
    def _start_fine(self) -> None:
        from amrst_gui.fine_job import refine_keeping_manual

        accepted = self._accepted
        assert accepted is not None  # plan() puts Accept coarse first
        if accepted.candidate.fine_points:
            log.info(
                "Fine registration runs on %s points, the set the trunk heading "
                "search verified this solution with (not fine.points).",
                accepted.candidate.fine_points,
            )
        # A trunk solution's full fit was made while matching: reuse it. From a
        # manual pose, Fine never silently replaces a better one.
        refine = functools.partial(refine_keeping_manual, matches=self.review.automatic)
        self._launch("fine", refine, self._by_role("analysis"), accepted, self._params)

    def _apply_fine(self, result: tuple) -> Callable[[], None]:
        self._fine, self._metrics["fine"], self._tree["fine"], decision = result
        self._fine_note = "" if decision is None else decision.why
        if decision is not None:
            (log.warning if decision.keep_manual else log.info)(self._fine_note)
        fine = self._fine
        return lambda: self.fine_finished.emit(fine)

    def _done_fine(self) -> bool:
        return self._fine is not None

    def _clear_fine(self) -> None:
        self._fine = None
        self._metrics.pop("fine", None)
        self._tree.pop("fine", None)

    def _summary_fine(self) -> str:
        return self._metrics_line("fine")

    # ---------------------------------------------------------------- export
    def _apply_export(self, result: list[Path]) -> Callable[[], None]:
        self._exported_result = self._fine or self._accepted
        reports = [p for p in result if p.name == "report.html"]
        self._last_report = reports[0] if reports else None
        folder = result[0].parent if result else "-"
        log.info("Exported to %s: %s", folder, ", ".join(p.name for p in result))
        return lambda: self.exported.emit(result)

    def _summary_export(self) -> str:
        return ""

    # --------------------------------------------------------------- helpers
    def _metrics_line(self, stage: str) -> str:
        m = self._metrics.get(stage)
        if m is None:
            return ""
        return f"RMSE {m.rmse_m:.4f} m, overlap {m.overlap_fraction:.0%}"
