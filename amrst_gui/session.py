"""Session: all state of one registration job, kept apart from the widgets.

State is exposed through read-only properties holding frozen engine results;
each change goes through a method that validates it, stores it and emits one
signal. The Session owns a :class:`~amrst_gui.runner.StepRunner` (the running job
and the steps still to run; the Session is its host) and a
:class:`~amrst_gui.review.Review` (the candidates and the technician's decisions);
each step's start, result and summary are in ``step_jobs``, the derived values in
``results``. Results are applied here, on the GUI thread. No widgets.
"""

from __future__ import annotations

import itertools
import logging
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
from PySide6.QtCore import QObject, Signal

from amrst.errors import AmrstError, Cancelled
from amrst_gui import jobs, steps
from amrst_gui.engine_process import EngineStopped
from amrst_gui.review import Review
from amrst_gui.runner import StepRunner
from amrst_gui.state import ScanId, ScanState
from amrst_gui.stored_result import StoredResultMixin

if TYPE_CHECKING:
    from collections.abc import Callable

    from amrst.params import RegistrationParams
    from amrst.pipeline import ScanAnalysis
    from amrst.types import Cloud

log = logging.getLogger("amrst_gui.session")


class Session(StoredResultMixin, QObject):
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
        # Per-scan state by scan id; the roles name the scans of the one link.
        self._scan_ids = (f"scan-{i}" for i in itertools.count(1))
        self._roles: dict[str, ScanId] = {r: next(self._scan_ids) for r in jobs.ROLES}
        self._scans: dict[ScanId, ScanState] = {
            sid: ScanState(sid) for sid in self._roles.values()
        }
        self.review = Review(
            lambda: (self._roles["target"], self._roles["source"]),
            lambda: self.analysis("source"),
        )
        self._reset_results()
        self._truth: np.ndarray | None = None
        self._truth_path: Path | None = None
        self.runner = StepRunner(self)
        self._job_params = self._params
        self._pending_paths: dict[str, Path] = {}
        self._stop_unverified = False
        self._manual_preview: np.ndarray | None = None
        self._pending_manual: tuple[np.ndarray, str] | None = None
        self._truth_at_load: np.ndarray | None = None
        self._last_report: Path | None = None
        # Asked before an unexported registration result is thrown away (closing,
        # new scans, swap, a re-run); the window sets it. Returns True to go on.
        self.discard_guard: Callable[[str], bool] | None = None

    # ------------------------------------------------------------ properties
    @property
    def params(self) -> RegistrationParams:
        """The current RegistrationParams (frozen)."""
        return self._params

    @property
    def busy(self) -> bool:
        """True from the start of a job (or chain of steps) until its end."""
        return self.runner.busy

    @property
    def running_step(self) -> str | None:
        """The step the running job computes, or None."""
        return self.runner.running_step

    def path(self, role: str) -> Path | None:
        """The file the ``role`` scan was read from."""
        return self._scan(role).path

    def cloud(self, role: str) -> Cloud | None:
        """The input Cloud for ``role`` ("target" or "source"), or None."""
        return self._scan(role).cloud

    def analysis(self, role: str) -> ScanAnalysis | None:
        """The ScanAnalysis of ``role`` (separation, then skeleton), or None."""
        return self._scan(role).analysis

    def scan_id(self, role: str) -> ScanId:
        """The id of the scan in ``role``: stable while that file stays loaded."""
        return self._roles[role]

    @property
    def last_report(self) -> Path | None:
        """The report.html the last export wrote, or None."""
        return self._last_report

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
        self._roles = {"target": self._roles["source"], "source": self._roles["target"]}
        self._reset_results()
        if self._truth is not None:
            from amrst.types import invert_transform

            self._truth = invert_transform(self._truth)
        log.info("Swapped: the reference (target) is now %s", self._name("target"))
        self.scans_swapped.emit()

    def set_params(self, params: RegistrationParams) -> None:
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
        if match_id == self.review.selected:
            return
        if match_id is not None and match_id not in self.review.candidate_ids():
            raise ValueError(f"no candidate with id {match_id}")
        self.review.selected = match_id
        self.selection_changed.emit(match_id)

    def reject_match(self, match_id: int) -> None:
        """Exclude a candidate from the coarse solution; emits ``review_changed``."""
        if match_id in self.review.rejected:
            return
        if match_id not in self.review.candidate_ids():
            raise ValueError(f"no candidate with id {match_id}")
        self.review.reject(match_id)
        log.info("Rejected match %s", self.review.describe(match_id))
        self.review_changed.emit(self.review.rejected)

    def restore_match(self, match_id: int) -> None:
        """Undo a rejection; emits ``review_changed``."""
        if match_id not in self.review.rejected:
            return
        self.review.restore(match_id)
        log.info("Restored match %s", self.review.describe(match_id))
        self.review_changed.emit(self.review.rejected)

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

    def export(
        self,
        out_dir: str | Path,
        cloud_format: str = "ply",
        parts=None,
        override: bool = False,
    ) -> None:
        """Write the results with ``amrst.results.export``; emits ``exported(paths)``.

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
        from amrst_gui.report import export_with_report, report_inputs

        self._launch(
            "export",
            export_with_report,
            Path(out_dir),
            kwargs,
            report_inputs(self),
            alone=True,
        )

    def cancel(self) -> None:
        """Ask the running job to stop; earlier results are kept."""
        step = self.runner.running_step
        if step is not None:
            if step in steps.UNSTOPPABLE and not self.runner.chained:
                message = (
                    f"{self._label(step)} cannot be stopped midway; "
                    "it finishes in a moment."
                )
                log.info(message)
                self.cancelled.emit(message)
                return
            log.info("Cancelling %s", self._label(step))
            # The running step may still finish (its result is kept); what
            # would have followed it is dropped either way.
            self.runner.cancel()

    def shutdown(self, timeout_s: float = 60.0) -> bool:
        """Cancel the running job and wait for the worker (window closing)."""
        return self.runner.shutdown(timeout_s)

    # ------------------------------------------------------------------ steps
    def run_step(self, step: str, auto: bool = False) -> None:
        """Run ``step`` and whatever earlier step is missing or stale, in order."""
        if self._refuse_if_busy(steps.plain_label(step)):
            return
        if not self.has_scans:
            self._fail("Open a target and a source scan first (File > Open).")
            return
        chain = self.plan(step)
        # Run all stops before it accepts an unverified candidate; an
        # explicit Accept coarse or Fine is the technician's own decision.
        self._stop_unverified = auto
        if self._replaces_result(chain[0]) and not self.may_discard(
            f"{steps.plain_label(chain[0])} again"
        ):
            return
        self.runner.run(chain)

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
        self._stop_unverified = False
        self.runner.run([*chain, "manual"])

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
            if not path.is_file() and not jobs.is_scan_spec(path):  # plot.e57#2
                self._fail(f"The file {path} does not exist.")
                return
        if not self.may_discard("Opening other scans"):
            return
        self._truth_at_load = self._truth
        self._pending_paths = dict(paths)
        self._launch("load", jobs.load_pair, paths, alone=True)

    # ----------------------------------------------------------- job running
    def _launch(self, step: str, fn, *args, alone: bool = False) -> None:
        """Start ``step``'s job (``alone``: not in a chain of steps)."""
        log.info("%s: started%s", self._label(step), self._params_text(step))
        # Parameters may change while the job runs: remember the ones it got.
        self._job_params = self._params
        if alone:
            self.runner.run_alone(step, fn, *args)
        else:
            self.runner.launch(step, fn, *args)

    def start_step(self, step: str) -> None:
        """Start ``step``'s job (the runner's host: ``step_jobs``' ``_start_<step>``)."""
        getattr(self, f"_start_{step}")()

    def step_returned(
        self, step: str, result: Any, seconds: float
    ) -> Callable[[], None]:
        """Store ``step``'s result and log it; returns what emits its signal."""
        self._timings[step] = seconds
        emit = self._apply(step, result)
        log.info(
            "%s: finished in %.2f s. %s", self._label(step), seconds, self.summary(step)
        )
        return emit

    def step_failed(self, step: str, exc: BaseException) -> None:
        """Report a job that raised: cancelled, an engine error, or a bug."""
        label = self._label(step)
        if isinstance(exc, Cancelled):
            log.warning("%s cancelled; earlier results are kept.", label)
            self.cancelled.emit(f"{label} cancelled; earlier results are kept.")
            return
        if isinstance(exc, AmrstError):
            # No parameter hint when the process itself ended.
            hint = "" if isinstance(exc, EngineStopped) else self._hint(step)
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

    def emit_started(self, step: str) -> None:
        """Emit ``step_started``."""
        self.step_started.emit(step)

    def emit_progress(self, fraction: float, message: str) -> None:
        """Emit ``progressed``."""
        self.progressed.emit(fraction, message)

    def emit_busy(self, busy: bool) -> None:
        """Emit ``busy_changed``."""
        self.busy_changed.emit(busy)

    def emit_chain_dropped(self, step: str) -> None:
        """Say that the steps after ``step`` were cancelled."""
        message = f"Stopped after {self._label(step)}; the later steps were cancelled."
        log.warning(message)
        self.cancelled.emit(message)

    def _apply(self, step: str, result: Any) -> Callable[[], None]:
        """Store a step's result and clear what was built on the old one.

        Returns the function that emits the step's signal.
        """
        if step in steps.STEPS:  # an engine step: later results are now stale
            self._clear_after(step)
            self._step_params[step] = self._job_params
        return getattr(self, f"_apply_{step}")(result)

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

    def _refuse_if_busy(self, what: str) -> bool:
        if not self.runner.busy:
            return False
        running = self._label(self.running_step or "a step")
        self._fail(f"Cannot {what} while {running} runs; wait or cancel it first.")
        return True

    def _fail(self, message: str) -> None:
        log.error(message)
        self.failed.emit(message)

    # ------------------------------------------------------------ scan state
    def _scan(self, role: str) -> ScanState:
        return self._scans[self._roles[role]]

    def _by_role(self, what: str) -> dict[str, Any]:
        """``{"target": ..., "source": ...}`` of one ScanState field (for the jobs)."""
        return {role: getattr(self._scan(role), what) for role in jobs.ROLES}

    def _set_analyses(self, analyses: dict[str, ScanAnalysis]) -> None:
        for role, analysis in analyses.items():
            self._scan(role).analysis = analysis

    def _reset_analyses(self) -> None:
        for scan in self._scans.values():
            scan.analysis = None

    def _set_loaded(self, clouds: dict[str, Cloud]) -> None:
        """New scans in their roles (new ids: nothing computed on the old ones holds)."""
        for role, cloud in clouds.items():
            del self._scans[self._roles[role]]
            sid = next(self._scan_ids)
            self._roles[role] = sid
            self._scans[sid] = ScanState(sid, self._pending_paths[role], cloud)
        self._reset_results()
        if self._truth is not None and self._truth is self._truth_at_load:
            log.info(
                "Cleared the truth (%s): it belonged to the scans before; load "
                "the new pair's truth with File > Load truth.",
                self._truth_path.name if self._truth_path else "truth",
            )
            self._truth, self._truth_path = None, None
