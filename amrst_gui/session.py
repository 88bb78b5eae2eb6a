"""Session: all state of one registration job, kept apart from the widgets.

State is exposed through read-only properties holding frozen engine results;
each change goes through a method that validates it, stores it and emits one
signal. Results are applied here, on the GUI thread. No widgets.

The Session owns a :class:`~amrst_gui.runner.StepRunner` (the running job and the
steps still to run; the Session is its host) and a :class:`~amrst_gui.review.Review`
(the candidates and the technician's decisions on them). A campaign's stored result
becomes result objects in ``stored_result``.

Each step of the step table (``amrst.pipeline.steps.STEPS``, plus the app's own
jobs ``load``, ``manual`` and ``export``) has one block of methods here, found by
the step's name: ``_start_<name>()`` launches its job (``_launch``) or refuses
(``runner.stop()``); ``_apply_<name>(result)`` stores the result and returns the
function that emits the step's signal; ``_done_<name>()`` says whether its result
exists (engine steps); ``_summary_<name>()`` is one line for the log;
``_clear_<name>()`` drops its result when an earlier step ran again. Adding a step:
one entry in the step table, one block here (``tests/gui/test_step_table.py``
checks that every step has its methods).
"""

from __future__ import annotations

import dataclasses
import functools
import itertools
import logging
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
from PySide6.QtCore import QObject, Signal

from amrst.errors import AmrstError, Cancelled, InvalidInput
from amrst.files.outcheck import same_file
from amrst_gui import jobs, steps
from amrst_gui.engine_process import EngineStopped
from amrst_gui.review import Review
from amrst_gui.runner import StepRunner
from amrst_gui.state import ScanId, ScanState
from amrst_gui.stored_result import STORED_ID, stored_params, stored_results

if TYPE_CHECKING:
    from collections.abc import Callable

    from amrst.campaign.stored import StoredLinkResult
    from amrst.measure import TreeMeasures
    from amrst.params import RegistrationParams
    from amrst.pipeline import MatchResult, ScanAnalysis
    from amrst.pipeline.refine import PoseQuality
    from amrst.review.verdict import Verdict
    from amrst.stages.candidates import Candidate, CoarseResult
    from amrst.stages.fine import FineResult
    from amrst.stages.metrics import CloudMetrics, TruthErrors
    from amrst.types import Cloud

log = logging.getLogger("amrst_gui.session")

# Source points sampled for the truth errors.
_TRUTH_SAMPLE = 20_000


class Session(QObject):
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

    # How the last export overrode a verdict that was not *registered*.
    _override: dict[str, str] | None

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
        # The truth file the last scans loaded cleared (it was the old pair's), or "".
        self.dropped_truth = ""
        self._pending_stored: StoredLinkResult | None = None
        # The scans are two of a forest plot (many trees): one-stem views do not apply.
        self.plot_pair = False
        self._pending_plot = False
        self._last_report: Path | None = None
        # The folder whose other pair's export the user agreed to replace.
        self._replace_folder: Path | None = None
        # Asked before unsaved work is thrown away (closing, new scans, swap, a
        # re-run): (the action, what it throws away, how to keep it); the window sets
        # it. Returns True to go on.
        self.discard_guard: Callable[[str, str, str], bool] | None = None
        # Work of the panels that new scans throw away (the Manual pose dock's point
        # pairs): each says what is unsaved ("" for nothing), and how to keep it.
        self.unsaved_work: list[tuple[Callable[[], str], str]] = []

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
        if self.out_of_date:
            self._fail(self.out_of_date)
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
        before = self.other_export(Path(out_dir))
        if before is not None and self._replace_folder != Path(out_dir).resolve():
            self._fail(
                f"Not exported: {out_dir} holds {before}. Choose another folder, or "
                "agree to replace it in the Export dialog."
            )
            return
        from amrst.results.export import refuse_inputs_in_out

        try:  # the export would write over a scan open here
            refuse_inputs_in_out(
                out_dir, [str(self.path(r)) for r in ("target", "source")]
            )
        except InvalidInput as exc:
            self._fail(f"Not exported: {exc}")
            return
        self._replace_folder = None
        kwargs = self.export_arguments(cloud_format, parts)
        kwargs["remove_stale"] = True  # one folder, one result: as the command does
        from amrst_gui.report import export_with_report, report_inputs

        self._launch(
            "export",
            export_with_report,
            Path(out_dir),
            kwargs,
            report_inputs(self),
            alone=True,
        )

    def other_export(self, out_dir: Path) -> str | None:
        """What ``out_dir`` holds that this pair's export would replace ("the export
        of S onto T", a plot's results...), or None (nothing, or this pair's own)."""
        from amrst.results.export import other_export

        target, source = self.path("target"), self.path("source")
        if target is None or source is None:
            return None
        return other_export(out_dir, [str(target), str(source)])

    def allow_replacing(self, out_dir: Path) -> None:
        """Let the next export replace another pair's export in ``out_dir`` (the
        user agreed)."""
        self._replace_folder = Path(out_dir).resolve()

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
        if self._refuse_if_busy(f"run {steps.plain_label(step)}"):
            return
        if not self.has_scans:
            self._fail(
                "Open a target and a source scan first (File > Open target…, Open source…)."
            )
            return
        if twice := self._one_scan_twice():
            self._fail(twice)
            return
        chain = self.plan(step)
        # Run all stops before it accepts an unverified candidate; an
        # explicit Accept coarse or Fine is the technician's own decision.
        self._stop_unverified = auto
        action = "Run all" if auto else f"{steps.plain_label(chain[0])} again"
        if self._replaces_result() and not self.may_discard(action, result_only=True):
            return
        self.runner.run(chain)

    def _one_scan_twice(self) -> str:
        """Why the target and the source are one file, or "". Checked when a step
        runs: scans are opened one at a time, and a new target may be the old source
        for a moment. Two files of the same points the separation step refuses
        (``jobs.separate_pair``): comparing them takes seconds on big scans."""
        target, source = self.path("target"), self.path("source")
        if target is not None and source is not None and same_file(target, source):
            return (
                f"The target and the source are the same file ({target}): open two "
                "scans of the tree."
            )
        return ""

    def run_all(self) -> None:
        """The automatic path: everything up to fine registration."""
        self.run_step("fine", auto=True)

    def accept_coarse(self) -> None:
        """Accept the candidate shown (the selected row), else the best one not
        rejected, and measure it."""
        chosen, coarse = self.review.selected, self.coarse
        before = self.review.preferred
        if (
            chosen is not None
            and chosen not in self.rejected
            and (coarse is None or int(coarse.candidate.id) != chosen)
            and not self.runner.busy
        ):
            self.review.preferred = chosen
            log.info("Accepting the selected match %s", self.review.describe(chosen))
            self.review_changed.emit(self.rejected)
        elif chosen is not None and chosen in self.rejected:
            log.info(
                "The selected match %s is rejected: the best one not rejected is "
                "accepted (restore it to accept it).",
                self.review.describe(chosen),
            )
        self.run_step("coarse")
        if not self.runner.busy and self.review.preferred != before:
            # Not run (a question declined, the scans refused): nothing changes.
            self.review.preferred = before
            self.review_changed.emit(self.rejected)

    def add_manual_pose(self, T_local: np.ndarray, how: str) -> None:
        """Score a hand-made ``T_target_source`` (local frames) as a candidate.

        It goes first in the candidate list (origin "manual"), verified and scored
        like the others; emits ``matches_changed``. Separates the scans first when
        that is missing (the score is measured on the preprocessed points).
        """
        if self._refuse_if_busy("add a manual pose"):
            return
        if not self.has_scans:
            self._fail(
                "Open a target and a source scan first (File > Open target…, Open source…)."
            )
            return
        chain = [s for s in self.plan("separate") if s == "separate"]
        if self.is_done("separate") and not self.is_stale("separate"):
            chain = []
        # Separating again drops the fine result, as the step's own button would.
        if (
            chain
            and self._replaces_result()
            and not self.may_discard(
                f"{steps.plain_label('separate')} again", result_only=True
            )
        ):
            return
        self._pending_manual = (np.asarray(T_local, float), how)
        self._stop_unverified = False
        self.runner.run([*chain, "manual"])

    def _start_load(self, paths: dict[str, Path], plot: bool = False) -> str:
        """Start reading the scans of ``paths``; return "" or why not."""
        from amrst import io

        why = self._busy_text("open scans")
        for path in paths.values():
            if why:
                break
            # What the path alone says (missing, empty, a folder or a pipe, an
            # extension no reader takes) is said before anything open is discarded.
            if not jobs.is_scan_spec(path):  # p.e57#2: its reader checks it
                try:
                    io.check_readable(path)
                except InvalidInput as exc:
                    why = str(exc)
                except PermissionError:
                    pass  # the reader says it, in its own words
        if why:
            self._fail(why)
            return why
        if not self.may_discard("Opening other scans"):
            return "you kept what was open"
        self._truth_at_load = self._truth
        self._pending_paths = dict(paths)
        self._pending_plot = plot
        # The parameters the scans will be shown with: a stored result's own.
        stored = self._pending_stored
        params = self._params if stored is None else stored_params(stored, self._params)
        self._launch(
            "load",
            functools.partial(jobs.load_pair, min_points=params.preprocess.min_points),
            paths,
            alone=True,
        )
        return ""

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
        """Start ``step``'s job (``_start_<step>``)."""
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
        if step == "load":  # the stored result waited for these scans only
            self._pending_stored = None
        if isinstance(exc, Cancelled):
            log.warning("%s cancelled; earlier results are kept.", label)
            self.cancelled.emit(f"{label} cancelled; earlier results are kept.")
            return
        if isinstance(exc, AmrstError):
            # No parameter hint when the process itself ended, or for one scan twice.
            plain = isinstance(exc, (EngineStopped, jobs.SameScans))
            hint = "" if plain else self._hint(step)
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

    def may_discard(self, action: str, *, result_only: bool = False) -> bool:
        """Ask ``discard_guard`` before ``action`` throws unsaved work away.

        That is an unexported result and, unless ``result_only`` (the scans stay),
        what ``unsaved_work`` names.
        """
        lost, keep = [], []
        if self.has_unexported_result:
            lost.append("the registration result (not exported)")
            keep.append(
                "undo the change (or restore the candidate), then Export (Ctrl+E) "
                "keeps the result"
                if self.out_of_date
                else "Export (Ctrl+E) keeps the result"
            )
        if not result_only:
            for say, how in self.unsaved_work:
                if text := say():
                    lost.append(text)
                    keep.append(how)
        if not lost or self.discard_guard is None:
            return True
        return self.discard_guard(action, " and ".join(lost), "; ".join(keep))

    def _replaces_result(self) -> bool:
        """Would running steps now replace an unexported fine result worth keeping?

        Only the fine result: accepting coarse again after a change of mind is part of
        the review and must not ask each time.
        """
        if self._fine is None or not self.has_unexported_result:
            return False
        # A result nobody wants (not "registered") is replaced without asking; one
        # whose candidate the review moved past is still worth asking about.
        verdict = self._verdict(as_shown=False)
        return verdict is not None and verdict.ok

    @staticmethod
    def _label(step: str) -> str:
        return steps.plain_label(step) if step in steps.LABELS else step

    def _refuse_if_busy(self, what: str) -> bool:
        """Say why ``what`` cannot start while a step runs; False when none runs."""
        why = self._busy_text(what)
        if why:
            self._fail(why)
        return bool(why)

    def _busy_text(self, what: str) -> str:
        """Why ``what`` (a verb phrase) cannot start now, or "" when it can."""
        if not self.runner.busy:
            return ""
        running = self._label(self.running_step or "a step")
        if what == f"run {running}":
            return f"{running} is running already; wait for it or cancel it (Esc)."
        return f"Cannot {what} while {running} runs; wait or cancel it first."

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
        self.dropped_truth = ""
        if self._truth is not None and self._truth is self._truth_at_load:
            self.dropped_truth = self._truth_path.name if self._truth_path else "truth"
            log.info(
                "Cleared the truth (%s): it belonged to the scans before; load "
                "the new pair's truth with File > Load truth.",
                self.dropped_truth,
            )
            self._truth, self._truth_path = None, None

    # ======================================================== results
    def _reset_results(self) -> None:
        self._reset_analyses()
        self.review.reset()
        self._accepted: CoarseResult | None = None
        self._fine: FineResult | None = None
        self._fine_note = ""  # from a manual pose: what Fine's check decided
        self._fine_dropped = False  # Fine's result dropped: the manual pose kept
        # What the technician judges a pose by, per stage and per manual candidate.
        self._quality: dict[str, PoseQuality] = {}
        self._manual_quality: dict[int, PoseQuality] = {}
        self._metrics: dict[str, CloudMetrics] = {}
        # stage -> {"target"|"source"|"merged": TreeMeasures}
        self._tree: dict[str, dict[str, TreeMeasures]] = {}
        self._timings: dict[str, float] = {
            k: v for k, v in getattr(self, "_timings", {}).items() if k == "load"
        }
        self._step_params: dict[str, RegistrationParams] = {}
        self._exported_result: CoarseResult | FineResult | None = None
        self._override = None
        self._stored: StoredLinkResult | None = None
        self._stored_matches: MatchResult | None = None
        self._stored_fine: FineResult | None = None

    def _clear_after(self, step: str) -> None:
        """Drop the results built on ``step``'s (each later step clears its own)."""
        # A stored pose and its candidate do not depend on the app's analyses.
        if step in ("separate", "skeleton") and self._stored_stands():
            return
        for name in steps.later_steps(step):
            getattr(self, f"_clear_{name}")()  # per step, below
            self._step_params.pop(name, None)
            self._timings.pop(name, None)

    # ---------------------------------------------------------------- review
    @property
    def matches(self) -> tuple[Candidate, ...]:
        """Ranked candidates, manual poses first, then the automatic ones."""
        return self.review.matches

    @property
    def match_result(self) -> MatchResult | None:
        """The MatchResult with the manual candidates in front, or None."""
        return self.review.match_result

    @property
    def manual_candidates(self) -> tuple[Candidate, ...]:
        """The manual candidates (origin "manual"), newest first."""
        return self.review.manual_candidates

    @property
    def manual_labels(self) -> dict[int, str]:
        """How each manual candidate was made ("3 point pairs", "typed", ...), by id."""
        return self.review.manual_labels

    @property
    def rejected(self) -> frozenset[int]:
        """Ids of the candidates the user rejected."""
        return self.review.rejected

    @property
    def selected_match(self) -> Candidate | None:
        """The Candidate shown in the views, or None."""
        return self.review.selected_match

    @property
    def coarse(self) -> CoarseResult | None:
        """CoarseResult from the candidate accepted by name, else the best not
        rejected (None if none is left)."""
        return self.review.coarse

    @property
    def coarse_message(self) -> str:
        """Why the coarse solution is what it is (or why there is none)."""
        return self.review.coarse_message

    @property
    def verdict(self) -> Verdict | None:
        """The verdict of the current registration, or None before matching; the
        stored verdict while a stored result stands."""
        return self._verdict(as_shown=True)

    def _verdict(self, *, as_shown: bool) -> Verdict | None:
        """``verdict``; with ``as_shown=False``, of the result itself even when the
        review moved past its candidate (:meth:`Review.verdict`)."""
        stored = self.stored
        if stored is not None and self._stored_fine is not None:
            from amrst.review.verdict import Verdict

            v = stored.verdict
            return Verdict(
                str(v.get("status", "needs review")),
                str(v.get("reason", "")),
                str(v.get("next_step", "")),
            )
        params = self._step_params.get("match") or self._params
        quality = self.pose_quality
        return self.review.verdict(
            self._accepted,
            self._fine,
            params,
            overlap=None if quality is None else quality.overlap,
            strength=None if quality is None else quality.strength,
            as_shown=as_shown,
        )

    @property
    def pose_quality(self) -> PoseQuality | None:
        """Overlap distances, strength and stem slices of the best pose so far (fine,
        else the accepted coarse, else the manual candidate proposed), or None."""
        for stage in ("fine", "coarse"):
            if stage in self._quality:
                return self._quality[stage]
        coarse = self.coarse
        if self._accepted is None and coarse is not None:
            return self._manual_quality.get(int(coarse.candidate.id))
        return None

    def stage_quality(self, stage: str) -> PoseQuality | None:
        """The PoseQuality of "coarse" or "fine", or None."""
        return self._quality.get(stage)

    @property
    def fine_dropped(self) -> bool:
        """True when Fine's result was dropped and the manual pose kept."""
        return self._fine is not None and self._fine_dropped

    # ----------------------------------------------------------------- state
    @property
    def has_scans(self) -> bool:
        """True when both target and source are loaded."""
        return all(self.cloud(r) is not None for r in jobs.ROLES)

    @property
    def accepted_coarse(self) -> CoarseResult | None:
        """The CoarseResult the user accepted, or None."""
        return self._accepted

    @property
    def fine(self) -> FineResult | None:
        """The FineResult, or None."""
        return self._fine

    @property
    def fine_note(self) -> str:
        """From a manual pose: whether Fine's result was kept, and why ("" else)."""
        return self._fine_note if self._fine is not None else ""

    @property
    def metrics(self) -> dict[str, CloudMetrics]:
        """CloudMetrics by stage ("coarse", "fine")."""
        return dict(self._metrics)

    @property
    def tree(self) -> dict[str, TreeMeasures]:
        """TreeMeasures of "target", "source" and "merged" under the best result so far
        (fine if done, else the accepted coarse); empty before."""
        return dict(self._tree.get("fine") or self._tree.get("coarse") or {})

    @property
    def timings(self) -> dict[str, float]:
        """Seconds per step that ran."""
        return dict(self._timings)

    @property
    def has_unexported_result(self) -> bool:
        """True when a coarse or fine result exists that was not exported."""
        final = self._fine or self._accepted
        return final is not None and final is not self._exported_result

    @property
    def final_transform(self) -> np.ndarray | None:
        """The best T_target_source so far (local frames, as the engine works):
        fine if done, else the accepted coarse."""
        if self._fine is not None:
            return self._fine.T_target_source
        if self._accepted is not None:
            return self._accepted.T_target_source
        return None

    def world(self, T_local: np.ndarray) -> np.ndarray:
        """A local-frame T_target_source in world coordinates (export, truth)."""
        from amrst.types import world_transform

        return world_transform(T_local, *self._pair_clouds())

    def local(self, T_world: np.ndarray) -> np.ndarray:
        """A world T_target_source between the scans' local frames (the views)."""
        from amrst.types import local_transform

        return local_transform(T_world, *self._pair_clouds())

    def _pair_clouds(self) -> tuple[Cloud, Cloud]:
        target, source = self.cloud("target"), self.cloud("source")
        assert target is not None  # no transform before both scans are loaded
        assert source is not None
        return target, source

    @property
    def result_params(self) -> RegistrationParams:
        """The parameters the current result was computed with (else the current)."""
        used = self._step_params.get("fine" if self._fine is not None else "coarse")
        return used or self._params

    @property
    def export_override(self) -> dict[str, str] | None:
        """How the last export overrode a verdict that was not *registered*."""
        return None if self._override is None else dict(self._override)

    def is_done(self, step: str) -> bool:
        """True when the step's result exists (stale or not)."""
        done = getattr(self, f"_done_{step}", None)  # per step, below
        return bool(done()) if done is not None else False

    @property
    def out_of_date(self) -> str:
        """Why the result cannot be exported as it stands, or "" when it can."""
        stale = [st for st in ("coarse", "fine") if self.is_stale(st)]
        if not stale:
            return ""
        return (
            f"{steps.plain_label(stale[-1])} is out of date: parameters or the "
            "review changed after it ran, so the files would not describe the "
            f"result. Run {steps.plain_label(stale[0])} again (or undo the "
            "change), then export."
        )

    def is_stale(self, step: str) -> bool:
        """True when a result exists but was computed with other parameters."""
        if not self.is_done(step):
            return False
        used = self._step_params.get(step)
        if used is None:
            return True
        from amrst.stages.candidates import Origin

        groups = steps.groups_for(step)
        if step in ("match", "coarse") and any(
            c.origin == Origin.TRUNK for c in self.matches
        ):
            # Trunk-search solutions were refined and verified with the fine settings.
            groups = (*groups, "fine")
        for group in groups:
            if not steps.values_equal(
                getattr(used, group), getattr(self._params, group)
            ):
                return True
        if step in ("coarse", "fine"):
            current = self.coarse
            assert self._accepted is not None  # is_done(step) holds
            accepted = self._accepted.candidate
            if (
                current is None
                or accepted is None
                or current.candidate.id != accepted.id
            ):
                return True
        return step == "fine" and self.is_stale("coarse")

    def plan(self, step: str) -> list[str]:
        """Steps ``run_step(step)`` runs: the missing or stale ones, then ``step``.

        From a stored pose, Accept coarse and Fine only separate first: the stored
        candidate needs no skeleton or match.
        """
        if step in ("coarse", "fine") and self._stored_stands():
            fresh = self.is_done("separate") and not self.is_stale("separate")
            chain = [] if fresh else ["separate"]
            if (
                step == "coarse"
                or not self.is_done("coarse")
                or self.is_stale("coarse")
            ):
                chain.append("coarse")
            if step == "fine":
                chain.append("fine")
            return chain
        out: list[str] = []
        for name in steps.STEPS[: steps.STEPS.index(step) + 1]:
            if out or name == step or not self.is_done(name) or self.is_stale(name):
                out.append(name)
        return out

    # --------------------------------------------------------- derived values
    def truth_errors(self) -> dict[str, TruthErrors]:
        """TruthErrors by stage ("coarse", "fine") when a truth file is loaded."""
        source = self.cloud("source")
        if self._truth is None or source is None:
            return {}
        from amrst.stages.metrics import truth_errors

        # The sample first, then to world coordinates: world_xyz copies every point.
        xyz = source.xyz[:: max(1, len(source) // _TRUTH_SAMPLE)] + source.offset
        out = {}
        coarse = self._accepted or self.coarse
        if coarse is not None:
            out["coarse"] = truth_errors(
                self.world(coarse.T_target_source), self._truth, xyz
            )
        if self._fine is not None:
            out["fine"] = truth_errors(
                self.world(self._fine.T_target_source), self._truth, xyz
            )
        return out

    def export_arguments(self, cloud_format: str, parts=None) -> dict[str, Any]:
        """Keyword arguments of ``amrst.results.export.export_registration`` (but out_dir)."""
        T_final = self.final_transform
        # Session.export, the only caller, returns early while this is None.
        assert T_final is not None
        assert self._accepted is not None  # a final transform needs an accepted one
        from amrst import __version__
        from amrst.results.documents import ResultRecord, result_documents

        fine = self._fine
        verdict = self.verdict
        quality = self.pose_quality
        context = self._transform_context()
        target, source = self.cloud("target"), self.cloud("source")
        assert target is not None  # a result needs both scans
        assert source is not None
        # The one result layout of the CLI, the app and the benchmark.
        record = ResultRecord(
            # The engine works between local frames; the files hold world transforms.
            T_target_source=self.world(T_final),
            T_coarse=self.world(self._accepted.T_target_source),
            target_name=target.name,
            source_name=source.name,
            target_file=context["target_file"],
            source_file=context["source_file"],
            coarse=self._accepted,
            fine=fine,
            metrics_coarse=self._metrics["coarse"].as_dict()
            if "coarse" in self._metrics
            else None,
            metrics_fine=self._metrics["fine"].as_dict()
            if "fine" in self._metrics and fine is not None
            else None,
            truth=self.truth_errors(),
            tree=self.tree,
            timings_s=dict(self._timings),
            rejected_match_ids=tuple(sorted(int(i) for i in self.review.rejected)),
            verdict=None if verdict is None else verdict.as_dict(),
            override=None if self._override is None else dict(self._override),
            quality=None if quality is None else quality.section(),
            strength=None if quality is None else dict(quality.strength.values),
            extra={k: context[k] for k in ("manual_pose",) if k in context},
            amrst_version=__version__,
        )
        kwargs: dict[str, Any] = {
            "target": target,
            "source": source,
            "T_target_source": record.T_target_source,
            # The parameters the result was computed with (export refuses stale ones).
            "params": self.result_params,
            "cloud_format": cloud_format,
            "documents": result_documents(record),
        }
        if parts is not None:
            kwargs["parts"] = tuple(parts)
        return kwargs

    def _transform_context(self) -> dict[str, Any]:
        coarse, fine = self._accepted, self._fine
        assert coarse is not None  # only exported results have a context
        extra: dict[str, Any] = {
            "target_file": str(self.path("target") or ""),
            "source_file": str(self.path("source") or ""),
            "stage": "fine" if fine is not None else "coarse",
            "coarse_confidence": float(coarse.confidence),
            "coarse_match_rank": None
            if coarse.candidate is None
            else int(coarse.candidate.rank),
            "coarse_origin": None
            if coarse.candidate is None
            else str(coarse.candidate.origin),
            "verified": bool(coarse.verified),
            "rejected_match_ids": sorted(int(i) for i in self.review.rejected),
        }
        verdict = self.verdict
        if verdict is not None:
            extra["verdict"] = verdict.as_dict()
        if self._override is not None:
            # A result that is not "registered" leaves only on purpose.
            extra["override"] = dict(self._override)
        if coarse.candidate is not None and coarse.candidate.origin == "manual":
            extra["manual_pose"] = {
                "how": self.review.manual_labels.get(int(coarse.candidate.id), ""),
                "T_target_source_as_given": self.world(
                    coarse.candidate.T_match
                ).tolist(),
            }
        if fine is not None:
            extra.update(
                fine_method=str(fine.method), fine_converged=bool(fine.converged)
            )
        return extra

    def metrics_report(self) -> dict[str, dict]:
        """Everything measured, as plain dicts for the export."""
        report: dict[str, dict] = {}
        for stage, m in self._metrics.items():
            report[stage] = dict(m.as_dict())
        if self._accepted is not None:
            c = self._accepted
            report.setdefault("coarse", {}).update(
                confidence=float(c.confidence),
                candidate_id=None if c.candidate is None else int(c.candidate.id),
                rejected_ids=sorted(int(i) for i in self.review.rejected),
            )
        if self._fine is not None:
            f = self._fine
            report.setdefault("fine", {}).update(
                converged=bool(f.converged),
                iterations=int(f.iterations),
                fitness=float(f.fitness),
                inlier_rmse_m=float(f.inlier_rmse_m),
                method=str(f.method),
            )
        for stage, err in self.truth_errors().items():
            report.setdefault(stage, {}).update(
                {f"truth_{k}": v for k, v in err.as_dict().items()}
            )
        if self.tree:
            report["tree"] = {name: m.as_dict() for name, m in self.tree.items()}
        quality = self.pose_quality
        if quality is not None:
            report["quality"] = quality.section()
            report["strength"] = dict(quality.strength.values)
        report["timings_s"] = dict(self._timings)
        verdict = self.verdict
        if verdict is not None:
            report["verdict"] = verdict.as_dict()
        if self._override is not None:
            report["override"] = dict(self._override)
        return report

    def summary(self, step: str) -> str:
        """One line about a step's result, for the log."""
        line = getattr(self, f"_summary_{step}", None)  # per step, below
        return str(line()) if line is not None else ""

    # --------------------------------------------------------------- helpers
    def _name(self, role: str) -> str:
        path, cloud = self.path(role), self.cloud(role)
        return path.name if path else (cloud.name if cloud is not None else "-")

    def _groups(self) -> list[str]:
        return [f.name for f in dataclasses.fields(self._params)]

    def _params_text(self, step: str) -> str:
        if step not in steps.STEPS:
            return ""
        parts = []
        for group in steps.own_groups(step):
            values = getattr(self._params, group, None)
            if values is None:
                continue
            fields = ", ".join(
                f"{f.name}={getattr(values, f.name)}"
                for f in dataclasses.fields(values)
            )
            parts.append(f"{group}({fields})")
        return " with " + "; ".join(parts) if parts else ""

    def _hint(self, step: str) -> str:
        groups = steps.own_groups(step)
        if not groups:
            return ""
        return (
            f" (Try other '{', '.join(groups)}' values in the Parameters dock, "
            "or a preset, and run the step again.)"
        )

    # ======================================================== the steps, one block each
    # ------------------------------------------------------------------ load
    def _apply_load(self, result: dict[str, Cloud]) -> Callable[[], None]:
        self._set_loaded(result)
        self.plot_pair = self._pending_plot
        roles = list(result)
        stored, self._pending_stored = self._pending_stored, None
        emit_stored = (
            None
            if stored is None or self.cloud("target") is None
            else self._apply_stored(stored)
        )

        def emit() -> None:
            for r in roles:
                self.scan_loaded.emit(r)
            if emit_stored is not None:
                emit_stored()

        return emit

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

    def _apply_manual(
        self, result: tuple[Candidate, PoseQuality]
    ) -> Callable[[], None]:
        cand, quality = result
        self._manual_quality[int(cand.id)] = quality
        self.review.add_manual(cand)
        log.info("Manual pose added: %s", cand.explanation)
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
        (
            self._accepted,
            self._metrics["coarse"],
            self._tree["coarse"],
            self._quality["coarse"],
        ) = result
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
        self._quality.pop("coarse", None)

    def _summary_coarse(self) -> str:
        return self._metrics_line("coarse")

    # ------------------------------------------------------------------ fine
    def _start_fine(self) -> None:
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
        refine = functools.partial(jobs.refine_pair, matches=self.review.automatic)
        self._launch("fine", refine, self._by_role("analysis"), accepted, self._params)

    def _apply_fine(self, result: tuple) -> Callable[[], None]:
        (
            self._fine,
            self._metrics["fine"],
            self._tree["fine"],
            self._quality["fine"],
            decision,
        ) = result
        self._fine_note = "" if decision is None else decision.why
        self._fine_dropped = decision is not None and decision.keep_manual
        if decision is not None:
            (log.warning if decision.keep_manual else log.info)(self._fine_note)
        fine = self._fine
        return lambda: self.fine_finished.emit(fine)

    def _done_fine(self) -> bool:
        return self._fine is not None

    def _clear_fine(self) -> None:
        self._fine = None
        self._fine_dropped = False
        self._metrics.pop("fine", None)
        self._tree.pop("fine", None)
        self._quality.pop("fine", None)

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
        over_all = (
            f"RMSE over all points {m.rmse_m:.4f} m, overlap {m.overlap_fraction:.0%}"
        )
        quality = self._quality.get(stage)
        if quality is None or quality.overlap.n_points_measured == 0:
            return over_all
        d = quality.overlap
        return (
            f"Where both scans saw the scene: median distance {d.median_m * 100:.1f} cm, "
            f"{d.within_2cm_fraction:.0%} within 2 cm ({over_all})."
        )

    # ------------------------------------------------------------ stored results
    def load_stored(
        self,
        target: str | Path,
        source: str | Path,
        stored: StoredLinkResult | None,
        *,
        plot: bool = False,
    ) -> str:
        """Read both scans (a worker job), then show ``stored`` as their result.

        ``stored`` None loads the scans alone (a link with no stored pose); ``plot``:
        two scans of a forest plot. Returns "" or why they are not read.
        """
        from pathlib import Path

        self._pending_stored = stored
        why = self._start_load({"target": Path(target), "source": Path(source)}, plot)
        if why:  # nothing pending
            self._pending_stored = None
        return why

    @property
    def stored(self) -> StoredLinkResult | None:
        """The stored result shown, until a step replaces its fine result."""
        return self._stored if self._fine is self._stored_fine else None

    def _stored_stands(self) -> bool:
        """True while the candidates are the stored pose's (no Match ran since)."""
        return (
            self._stored is not None and self.review.automatic is self._stored_matches
        )

    def _apply_stored(self, stored: StoredLinkResult) -> Callable[[], None]:
        """Put a stored link result in place of the computed steps."""
        params = stored_params(stored, self._params)
        same_params = steps.values_equal(params, self._params)
        self._params = params
        source = self.cloud("source")
        # On the GUI thread: the centre (for "same solution" tests) from every n-th
        # point, at most about 100,000, so that a big scan does not stall it.
        centre = (
            source.xyz[:: max(1, len(source.xyz) // 100_000)].mean(axis=0)
            if source is not None
            else np.zeros(3)
        )
        T = self.local(np.asarray(stored.T_world, float))
        got = stored_results(stored, params, T, centre)
        self.review.automatic = got.matches
        self._accepted, self._fine = got.coarse, got.fine
        # Already on disk: switching trees never asks to discard it.
        self._exported_result = got.fine
        self.review.selected = STORED_ID
        self.review.link_review.accepted_pose = T
        self._metrics.update(got.metrics)
        self._tree["fine"] = got.tree
        if got.quality is not None:
            self._quality["fine"] = got.quality
        for step in ("match", "coarse", "fine"):
            self._step_params[step] = params
        self._stored = stored
        self._stored_matches, self._stored_fine = got.matches, got.fine
        truth, fine = got.truth, got.fine
        if truth is not None:  # the tree's truth file, for this link
            self._truth, self._truth_path = truth, None
        log.info(
            "Showing the stored result of %s: %s (no step ran).",
            stored.label,
            stored.verdict.get("status", ""),
        )

        def emit() -> None:
            # Not coarse_accepted: every view drawn on it draws again on
            # fine_finished (the fine result is the stored pose too), and each
            # redraw costs a switch between trees time.
            if not same_params:  # the Parameters dock rebuilds on it
                self.params_changed.emit(params)
            if truth is not None:
                self.truth_loaded.emit(truth)
            self.matches_changed.emit()
            self.fine_finished.emit(fine)

        return emit
