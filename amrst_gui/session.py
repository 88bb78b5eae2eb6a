"""Session: all state of one registration job, kept apart from the widgets.

State is exposed through read-only properties holding frozen engine results;
each change goes through a method that validates it, stores it and emits one
signal. Work runs through ``workers.run_stage``; results
are applied here, on the GUI thread. This module imports no widgets.
"""

from __future__ import annotations

import itertools
import logging
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
from PySide6.QtCore import QObject, Signal

from amrst_gui import jobs, steps, workers
from amrst_gui.review import Review
from amrst_gui.runner import RunnerMixin
from amrst_gui.state import ScanId, ScanState
from amrst_gui.stored_result import StoredResultMixin

if TYPE_CHECKING:
    from collections.abc import Callable

    from amrst.params import RegistrationParams
    from amrst.pipeline import ScanAnalysis
    from amrst.types import Cloud

log = logging.getLogger("amrst_gui.session")


class Session(RunnerMixin, StoredResultMixin, QObject):
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
        return self._busy

    @property
    def running_step(self) -> str | None:
        """The step the running job computes, or None."""
        return self._job.name if self._job is not None else None

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

        self._chain = []
        self._set_busy(True)
        self._launch(
            "export", export_with_report, Path(out_dir), kwargs, report_inputs(self)
        )

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
