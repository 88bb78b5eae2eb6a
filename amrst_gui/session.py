"""Session: all state of one registration job, kept apart from the widgets.

State is exposed through read-only properties holding frozen engine results;
each change goes through a method that validates it, stores it and emits one
signal (STYLE.md section 4). Work runs through ``workers.run_stage``; results
are applied here, on the GUI thread. This module imports no widgets.
"""

from __future__ import annotations

import functools
import logging
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
from PySide6.QtCore import QObject, Signal

from amrst.errors import AmrstError, Cancelled
from amrst_gui import jobs, steps, workers
from amrst_gui.results import ResultsMixin

if TYPE_CHECKING:
    from collections.abc import Callable

log = logging.getLogger("amrst_gui.session")


class Session(ResultsMixin, QObject):
    """One target/source pair, its parameters, results and review decisions.

    Signals (all emitted on the GUI thread):
    ``scan_loaded(role)``, ``scans_swapped()``, ``params_changed(params)``,
    ``separation_finished()``, ``skeletons_finished()``, ``matches_changed()``,
    ``review_changed(rejected_ids)``, ``selection_changed(match_id or None)``,
    ``coarse_accepted(CoarseResult)``, ``fine_finished(FineResult)``,
    ``truth_loaded(T_target_source)``, ``exported(paths)``,
    ``step_started(step)``, ``progressed(fraction, message)``,
    ``busy_changed(bool)``, ``failed(message)``, ``cancelled(message)``.
    """

    scan_loaded = Signal(str)
    scans_swapped = Signal()
    params_changed = Signal(object)
    separation_finished = Signal()
    skeletons_finished = Signal()
    matches_changed = Signal()
    review_changed = Signal(frozenset)
    selection_changed = Signal(object)
    coarse_accepted = Signal(object)
    fine_finished = Signal(object)
    truth_loaded = Signal(object)
    exported = Signal(list)
    step_started = Signal(str)
    progressed = Signal(float, str)
    busy_changed = Signal(bool)
    failed = Signal(str)
    cancelled = Signal(str)
    manual_preview_changed = Signal(object)

    def __init__(self, parent: QObject | None = None) -> None:
        super().__init__(parent)
        from amrst.params import RegistrationParams

        self._params = RegistrationParams()
        self._paths: dict[str, Path | None] = dict.fromkeys(jobs.ROLES)
        self._clouds: dict[str, Any] = dict.fromkeys(jobs.ROLES)
        self._reset_results()
        self._truth: np.ndarray | None = None
        self._truth_path: Path | None = None
        self._job: workers.StageJob | None = None
        self._chain: list[str] = []
        self._chain_dropped = False
        self._busy = False
        self._job_params = self._params
        self._pending_paths: dict[str, Path] = {}
        self._closing = False
        self._stop_unverified = False
        self._manual_preview: np.ndarray | None = None
        self._pending_manual: tuple[np.ndarray, str] | None = None
        self._truth_at_load: np.ndarray | None = None
        # Asked before an unexported registration result is thrown away (closing,
        # new scans, swap, a re-run); the window sets it. Returns True to go on.
        self.discard_guard: Callable[[str], bool] | None = None

    # ------------------------------------------------------------ properties
    @property
    def params(self) -> Any:
        """The current RegistrationParams (frozen)."""
        return self._params

    @property
    def busy(self) -> bool:
        """True from the start of a job (or chain of steps) until its end."""
        return self._busy

    @property
    def running_step(self) -> str | None:
        """The step the running job computes, or None."""
        return self._job.name if self._job is not None else None

    def path(self, role: str) -> Path | None:
        """The file the ``role`` scan was read from."""
        return self._paths[role]

    def cloud(self, role: str) -> Any:
        """The input Cloud for ``role`` ("target" or "source"), or None."""
        return self._clouds[role]

    @property
    def truth(self) -> np.ndarray | None:
        """The known (4, 4) T_target_source from a truth file, or None."""
        return self._truth

    @property
    def truth_path(self) -> Path | None:
        """The truth file that was loaded."""
        return self._truth_path

    # --------------------------------------------------------------- changes
    def load_scans(self, target: str | Path, source: str | Path) -> None:
        """Read both scans in a worker; emits ``scan_loaded`` once per role."""
        self._start_load({"target": Path(target), "source": Path(source)})

    def load_scan(self, role: str, path: str | Path) -> None:
        """Read one scan in a worker; emits ``scan_loaded(role)``."""
        if role not in jobs.ROLES:
            raise ValueError(f"role must be 'target' or 'source', not {role!r}")
        self._start_load({role: Path(path)})

    def swap_scans(self) -> None:
        """Make the source the reference and vice versa; emits ``scans_swapped``."""
        if self._refuse_if_busy("swap the scans") or not self.may_discard(
            "Swapping the scans"
        ):
            return
        self._clouds = {
            "target": self._clouds["source"],
            "source": self._clouds["target"],
        }
        self._paths = {"target": self._paths["source"], "source": self._paths["target"]}
        self._reset_results()
        if self._truth is not None:
            from amrst.types import invert_transform

            self._truth = invert_transform(self._truth)
        log.info("Swapped: the reference (target) is now %s", self._name("target"))
        self.scans_swapped.emit()

    def set_params(self, params: Any) -> None:
        """Use new RegistrationParams; emits ``params_changed`` if they differ."""
        if steps.values_equal(params, self._params):
            return
        if self._refuse_if_busy("change the parameters"):
            # A chain of steps must run on one set of parameters.
            self.params_changed.emit(self._params)
            return
        changed = [
            g
            for g in self._groups()
            if not steps.values_equal(getattr(params, g), getattr(self._params, g))
        ]
        self._params = params
        log.info("Parameters changed: %s", ", ".join(changed) or "none")
        self.params_changed.emit(params)

    def select_match(self, match_id: int | None) -> None:
        """Show one candidate in the views; emits ``selection_changed``."""
        if match_id == self._selected:
            return
        if match_id is not None and match_id not in self._candidate_ids():
            raise ValueError(f"no candidate with id {match_id}")
        self._selected = match_id
        self.selection_changed.emit(match_id)

    def reject_match(self, match_id: int) -> None:
        """Exclude a candidate from the coarse solution; emits ``review_changed``."""
        if match_id in self._rejected:
            return
        if match_id not in self._candidate_ids():
            raise ValueError(f"no candidate with id {match_id}")
        self._rejected = self._rejected | {match_id}
        self._remember_rejection(match_id)
        log.info("Rejected match %s", self._describe_match(match_id))
        self.review_changed.emit(self._rejected)

    def restore_match(self, match_id: int) -> None:
        """Undo a rejection; emits ``review_changed``."""
        if match_id not in self._rejected:
            return
        self._forget_rejection(match_id)
        self._rejected = self._rejected - {match_id}
        log.info("Restored match %s", self._describe_match(match_id))
        self.review_changed.emit(self._rejected)

    def load_truth(self, path: str | Path) -> None:
        """Read ``T_target_source`` from a truth JSON.

        Emits ``truth_loaded`` or ``failed``.
        """
        path = Path(path)
        try:
            T = jobs.read_truth(path)
        except ValueError as exc:
            self._fail(str(exc))
            return
        self._truth, self._truth_path = T, path
        log.info("Loaded truth from %s", path)
        self.truth_loaded.emit(T)

    def set_manual_preview(self, T_local: np.ndarray | None) -> None:
        """Show a pose being made by hand in the overlay; emits
        ``manual_preview_changed``."""
        same = (T_local is None and self._manual_preview is None) or (
            T_local is not None
            and self._manual_preview is not None
            and np.array_equal(T_local, self._manual_preview)
        )
        if not same:
            self._manual_preview = None if T_local is None else np.array(T_local)
            self.manual_preview_changed.emit(self._manual_preview)

    @property
    def manual_preview(self) -> np.ndarray | None:
        """The pose being made by hand (pairs or nudge), or None."""
        return self._manual_preview

    def report_error(self, message: str) -> None:
        """Show a problem found outside a job (bad typed input); emits ``failed``."""
        self._fail(message)

    # ------------------------------------------------------------------ jobs
    def run_step(self, step: str, auto: bool = False) -> None:
        """Run ``step`` and whatever earlier step is missing or stale, in order."""
        if self._refuse_if_busy(steps.plain_label(step)):
            return
        if not self.has_scans:
            self._fail("Open a target and a source scan first (File > Open).")
            return
        chain = self.plan(step)
        # Run all stops before it accepts an unverified candidate (issue 13); an
        # explicit Accept coarse or Fine is the technician's own decision.
        self._stop_unverified = auto
        if self._replaces_result(chain[0]) and not self.may_discard(
            f"{steps.plain_label(chain[0])} again"
        ):
            return
        self._chain = chain
        self._set_busy(True)
        self._start_next()

    def run_all(self) -> None:
        """The automatic path: everything up to fine registration."""
        self.run_step("fine", auto=True)

    def accept_coarse(self) -> None:
        """Accept the coarse solution (best candidate not rejected) and measure it."""
        self.run_step("coarse")

    def add_manual_pose(self, T_local: np.ndarray, how: str) -> None:
        """Score a hand-made ``T_target_source`` (local frames) as a candidate.

        It goes first in the candidate list (origin "manual"), verified and scored
        like the others; emits ``matches_changed``. Separates the scans first when
        that is missing (the score is measured on the preprocessed points).
        """
        if self._refuse_if_busy("add a manual pose"):
            return
        if not self.has_scans:
            self._fail("Open a target and a source scan first (File > Open).")
            return
        self._pending_manual = (np.asarray(T_local, float), how)
        chain = [s for s in self.plan("separate") if s == "separate"]
        if self.is_done("separate") and not self.is_stale("separate"):
            chain = []
        self._chain = [*chain, "manual"]
        self._stop_unverified = False
        self._set_busy(True)
        self._start_next()

    def export(
        self,
        out_dir: str | Path,
        cloud_format: str = "ply",
        parts=None,
        override: bool = False,
    ) -> None:
        """Write the results with ``amrst.export``; emits ``exported(paths)``.

        A result whose verdict is not *registered* is written only with ``override``
        (the window asks), and the override is recorded in the files.
        """
        if self._refuse_if_busy("export"):
            return
        if self.final_transform is None:
            self._fail("Nothing to export yet: accept a coarse solution first.")
            return
        verdict = self.verdict
        if verdict is not None and not verdict.ok and not override:
            self._fail(
                f"Not exported: the verdict is '{verdict.status}'. {verdict.reason} "
                "Export anyway only on purpose (the files then record the override)."
            )
            return
        self._override = (
            None
            if verdict is None or verdict.ok
            else {"verdict_status": verdict.status, "by": "user, in amrst-gui"}
        )
        stale = [st for st in ("coarse", "fine") if self.is_stale(st)]
        if stale:
            self._fail(
                f"{steps.plain_label(stale[-1])} is out of date: parameters or the "
                "review changed after it ran, so the files would not describe the "
                f"result. Run {steps.plain_label(stale[0])} again (or undo the "
                "change), then export."
            )
            return
        kwargs = self.export_arguments(cloud_format, parts)
        self._chain = []
        self._set_busy(True)
        self._launch("export", jobs.export_pair, Path(out_dir), kwargs)

    def cancel(self) -> None:
        """Ask the running job to stop; earlier results are kept."""
        if self._job is not None:
            if self._job.name in steps.UNSTOPPABLE and not self._chain:
                message = (
                    f"{self._label(self._job.name)} cannot be stopped midway; "
                    "it finishes in a moment."
                )
                log.info(message)
                self.cancelled.emit(message)
                return
            log.info("Cancelling %s", self._label(self._job.name))
            # The running step may still finish (its result is kept); what
            # would have followed it is dropped either way.
            self._chain_dropped = bool(self._chain)
            self._chain = []
            self._job.cancel()

    def shutdown(self, timeout_s: float = 60.0) -> bool:
        """Cancel the running job and wait for the worker (window closing)."""
        self._closing = True
        self._chain = []
        if self._job is not None:
            self._job.discard()
            self._job = None
        self._busy = False
        return workers.wait_for_workers(timeout_s)

    # ------------------------------------------------------------- internals
    def _start_load(self, paths: dict[str, Path]) -> None:
        if self._refuse_if_busy("open scans"):
            return
        for path in paths.values():
            if path.is_dir():
                self._fail(
                    f"{path} is a folder, not a point-cloud file: open or drop the "
                    "scan files themselves."
                )
                return
            if not path.is_file():
                self._fail(f"The file {path} does not exist.")
                return
        if not self.may_discard("Opening other scans"):
            return
        self._truth_at_load = self._truth
        self._chain = []
        self._pending_paths = dict(paths)
        self._set_busy(True)
        self._launch("load", jobs.load_pair, paths)

    def _start_next(self) -> None:
        step = self._chain.pop(0)
        p, an = self._params, self._analyses
        if step == "separate":
            self._launch(step, jobs.separate_pair, dict(self._clouds), p)
        elif step == "skeleton":
            self._launch(step, jobs.skeletonise_pair, dict(an), p)
        elif step == "match":
            manual = tuple(
                (c.T_match, int(c.id), self._manual_labels.get(int(c.id), ""))
                for c in self._manual
            )
            self._launch(
                step, functools.partial(jobs.match_pair, manual=manual), dict(an), p
            )
        elif step == "manual":
            assert self._pending_manual is not None  # set by add_manual_pose
            T, how = self._pending_manual
            cid = self._next_manual_id()
            self._manual_labels[cid] = how
            self._launch(step, jobs.score_manual_pair, dict(an), T, cid, how, p)
        elif step == "coarse":
            coarse = self.coarse
            if coarse is None:
                self._chain = []
                self._set_busy(False)
                self._fail(f"No coarse solution to accept: {self.coarse_message}")
                return
            if self._stop_unverified and not coarse.verified:
                self._chain = []
                self._set_busy(False)
                verdict = self.verdict
                self._fail(
                    "Run all stopped before accepting an unverified candidate. "
                    + (verdict.text() if verdict is not None else coarse.message)
                )
                return
            self._launch(step, jobs.evaluate_coarse, dict(an), coarse, p)
        elif step == "fine":
            points = self._accepted.candidate.fine_points
            if points:
                log.info(
                    "Fine registration runs on %s points, the set the trunk heading "
                    "search verified this solution with (not fine.points).",
                    points,
                )
            # A trunk solution's full fit was made while matching: reuse it.
            refine = functools.partial(jobs.refine_pair, matches=self._matches)
            self._launch(step, refine, dict(an), self._accepted, p)

    def _launch(self, step: str, fn, *args) -> None:
        log.info("%s: started%s", self._label(step), self._params_text(step))
        # Parameters may change while the job runs: remember the ones it got.
        self._job_params = self._params
        self._job = workers.run_stage(
            fn,
            *args,
            name=step,
            on_result=lambda payload: self._on_job_returned(step, payload),
            on_error=lambda exc: self._on_job_errored(step, exc),
            on_progress=self.progressed.emit,
        )
        self.step_started.emit(step)

    def _on_job_returned(self, step: str, payload: tuple) -> None:
        result, seconds = payload
        self._job = None
        self._timings[step] = seconds
        emit = self._apply(step, result)
        log.info(
            "%s: finished in %.2f s. %s", self._label(step), seconds, self.summary(step)
        )
        if self._chain:
            emit()
            self._start_next()
            return
        self._set_busy(False)
        emit()
        if self._chain_dropped:
            self._chain_dropped = False
            message = (
                f"Stopped after {self._label(step)}; the later steps were cancelled."
            )
            log.warning(message)
            self.cancelled.emit(message)

    def _on_job_errored(self, step: str, exc: BaseException) -> None:
        self._job = None
        self._chain = []
        self._chain_dropped = False
        self._set_busy(False)
        label = self._label(step)
        if isinstance(exc, Cancelled):
            log.warning("%s cancelled; earlier results are kept.", label)
            self.cancelled.emit(f"{label} cancelled; earlier results are kept.")
            return
        if isinstance(exc, AmrstError):
            hint = self._hint(step)
            self._fail(f"{label} failed: {exc}{hint}")
        else:
            log.error(
                "Unexpected error in %s:\n%s",
                label,
                getattr(exc, "__traceback_text__", repr(exc)),
            )
            self._fail(
                f"{label} failed with an unexpected error: {type(exc).__name__}: {exc}"
            )

    def _apply(self, step: str, result: Any):
        """Store a step's result and clear what was built on the old one.

        Returns the function that emits the step's signal.
        """
        if step == "load":
            for role, cloud in result.items():
                self._clouds[role] = cloud
                self._paths[role] = self._pending_paths[role]
            self._reset_results()
            if self._truth is not None and self._truth is self._truth_at_load:
                log.info(
                    "Cleared the truth (%s): it belonged to the scans before; load "
                    "the new pair's truth with File > Load truth.",
                    self._truth_path.name if self._truth_path else "truth",
                )
                self._truth, self._truth_path = None, None
            roles = list(result)

            def emit_loaded() -> None:
                for r in roles:
                    self.scan_loaded.emit(r)

            return emit_loaded
        if step == "export":
            self._exported_result = self._fine or self._accepted
            folder = result[0].parent if result else "-"
            names = ", ".join(p.name for p in result)
            log.info("Exported to %s: %s", folder, names)
            return lambda: self.exported.emit(result)
        if step == "manual":
            self._manual = (result, *self._manual)
            self._rejected = self._rejected - {int(result.id)}
            self._selected = int(result.id)
            log.info("Manual pose added: %s", result.explanation)
            return self.matches_changed.emit
        self._clear_after(step)
        self._step_params[step] = self._job_params
        if step in ("separate", "skeleton"):
            self._analyses = result
            sig = (
                self.separation_finished
                if step == "separate"
                else self.skeletons_finished
            )
            return sig.emit
        if step == "match":
            self._matches, self._manual = result
            self._rejected = self._carry_review()
            cands = [c for c in self.matches if c.id not in self._rejected]
            self._selected = cands[0].id if cands else None
            return self.matches_changed.emit
        if step == "coarse":
            self._accepted, self._metrics["coarse"], self._tree["coarse"] = result
            self._accepted_pose = self._accepted.T_target_source
            return lambda: self.coarse_accepted.emit(self._accepted)
        self._fine, self._metrics["fine"], self._tree["fine"] = result
        return lambda: self.fine_finished.emit(self._fine)

    def may_discard(self, action: str) -> bool:
        """Ask ``discard_guard`` before ``action`` throws an unexported result away."""
        if not self.has_unexported_result or self.discard_guard is None:
            return True
        return self.discard_guard(action)

    def _replaces_result(self, first_step: str) -> bool:
        """Would a chain starting at ``first_step`` replace an unexported fine result?

        Only the fine result: accepting coarse again after a change of mind is part of
        the review and must not ask each time.
        """
        if self._fine is None or not self.has_unexported_result:
            return False
        # A result nobody wants (not "registered") is replaced without asking.
        verdict = self.verdict
        return verdict is not None and verdict.ok

    @staticmethod
    def _label(step: str) -> str:
        return steps.plain_label(step) if step in steps.LABELS else step

    def _set_busy(self, busy: bool) -> None:
        self._busy = busy
        if not self._closing:
            self.busy_changed.emit(busy)

    def _refuse_if_busy(self, what: str) -> bool:
        if not self._busy:
            return False
        running = self._label(self.running_step or "a step")
        self._fail(f"Cannot {what} while {running} runs; wait or cancel it first.")
        return True

    def _fail(self, message: str) -> None:
        log.error(message)
        self.failed.emit(message)
