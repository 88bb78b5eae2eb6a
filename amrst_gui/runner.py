"""Running the steps: plan, chain, launch in a worker, apply the result, report.

Generic over the step table: ``_start_next`` and ``_apply`` call the step's own
``_start_<name>`` / ``_apply_<name>`` (``amrst_gui/step_jobs.py``). A mixin of the
Session; no widgets.
"""

from __future__ import annotations

import logging
from typing import TYPE_CHECKING, Any

import numpy as np

from amrst.errors import AmrstError, Cancelled
from amrst_gui import engine_process, jobs, steps, workers

if TYPE_CHECKING:
    from collections.abc import Callable
    from pathlib import Path

    from amrst.params import RegistrationParams
    from amrst.stages.fine import FineResult

log = logging.getLogger("amrst_gui.session")

# The jobs that run in the engine process (``engine_process``): the engine's
# steps and Export (it transforms and writes every point). Loading stays here: it
# reads in chunks that release the GIL, and the scans are needed here first.
ENGINE_STEPS = frozenset({*steps.STEPS, "manual", "export"})


class RunnerMixin:
    """The job machinery of the Session."""

    if TYPE_CHECKING:
        _params: RegistrationParams
        _job_params: RegistrationParams
        _job: workers.StageJob | None
        _chain: list[str]
        _chain_dropped: bool
        _busy: bool
        _closing: bool
        _stop_unverified: bool
        _pending_manual: tuple[np.ndarray, str] | None
        _pending_paths: dict[str, Path]
        _truth: np.ndarray | None
        _truth_at_load: np.ndarray | None
        _timings: dict[str, float]
        _step_params: dict[str, RegistrationParams]
        _fine: FineResult | None
        discard_guard: Callable[[str], bool] | None
        step_started: Any
        progressed: Any
        busy_changed: Any
        failed: Any
        cancelled: Any

        def plan(self, step: str) -> list[str]: ...
        def is_done(self, step: str) -> bool: ...
        def is_stale(self, step: str) -> bool: ...
        def summary(self, step: str) -> str: ...
        def _clear_after(self, step: str) -> None: ...
        def _params_text(self, step: str) -> str: ...
        def _hint(self, step: str) -> str: ...
        @property
        def has_scans(self) -> bool: ...
        @property
        def has_unexported_result(self) -> bool: ...
        @property
        def verdict(self) -> Any: ...
        @property
        def running_step(self) -> str | None: ...

    # ------------------------------------------------------------------ jobs
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
            if not path.is_file() and not jobs.is_scan_spec(path):  # plot.e57#2
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
        getattr(self, f"_start_{step}")()

    def _launch(self, step: str, fn, *args) -> None:
        log.info("%s: started%s", self._label(step), self._params_text(step))
        # Parameters may change while the job runs: remember the ones it got.
        self._job_params = self._params
        if step in ENGINE_STEPS:  # their GIL would stall the window
            fn = engine_process.in_engine(fn, step not in steps.UNSTOPPABLE)
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
        if step == "load":  # its imports run while the user looks at the scans
            engine_process.ENGINE.start()
        emit = self._apply(step, result)
        if step == "load":  # the old scans are dropped: the engine lets go too
            engine_process.ENGINE.trim()
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
            # No parameter hint when the process itself ended.
            hint = (
                ""
                if isinstance(exc, engine_process.EngineStopped)
                else self._hint(step)
            )
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
