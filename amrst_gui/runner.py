"""Running the session's jobs one at a time: a chain of steps, Cancel, shutdown.

The :class:`StepRunner` knows the steps by name only. Its host (the Session)
starts a step's job, stores the result and words what happened; the runner holds
the running job and the steps still to run, and says when the session is busy.
No widgets.
"""

from __future__ import annotations

import logging
from typing import TYPE_CHECKING, Any, Protocol

from amrst_gui import engine_process, steps, workers

if TYPE_CHECKING:
    from collections.abc import Callable

log = logging.getLogger("amrst_gui.session")

# The jobs that run in the engine process (``engine_process``): the engine's
# steps and Export (it transforms and writes every point). Loading stays here: it
# reads in chunks that release the GIL, and the scans are needed here first.
ENGINE_STEPS = frozenset({*steps.STEPS, "manual", "export"})


class RunnerHost(Protocol):
    """What a :class:`StepRunner` needs of its host."""

    def start_step(self, step: str) -> None:
        """Start ``step``'s job with :meth:`StepRunner.launch` (or refuse, with
        :meth:`StepRunner.stop`)."""

    def step_returned(
        self, step: str, result: Any, seconds: float
    ) -> Callable[[], None]:
        """Store ``step``'s result; return what emits its signal."""

    def step_failed(self, step: str, exc: BaseException) -> None:
        """Report a job that raised (``Cancelled`` included)."""

    def emit_started(self, step: str) -> None:
        """A step's job started."""

    def emit_progress(self, fraction: float, message: str) -> None:
        """A running job's progress."""

    def emit_busy(self, busy: bool) -> None:
        """The runner became busy or idle."""

    def emit_chain_dropped(self, step: str) -> None:
        """``step`` finished after a Cancel that dropped the steps after it."""


class StepRunner:
    """One job at a time; a chain of steps, each started once the one before it
    was applied."""

    def __init__(self, host: RunnerHost) -> None:
        self._host = host
        self.job: workers.StageJob | None = None
        self._chain: list[str] = []
        self._chain_dropped = False
        self._busy = False
        self._closing = False
        self._what = ""  # the running job, as a call waiting for the engine names it

    @property
    def busy(self) -> bool:
        """True from the start of a job (or chain of steps) until its end."""
        return self._busy

    @property
    def running_step(self) -> str | None:
        """The step the running job computes, or None."""
        return self.job.name if self.job is not None else None

    @property
    def writing(self) -> bool:
        """True while Export writes its files (it runs to its end once it does)."""
        return self.running_step == "export" and engine_process.ENGINE.serving(
            self._what
        )

    @property
    def chained(self) -> bool:
        """True while steps wait to run after the running one."""
        return bool(self._chain)

    def run(self, chain: list[str]) -> None:
        """Become busy and run the steps of ``chain`` in order."""
        self._chain = list(chain)
        self._set_busy(True)
        self._start_next()

    def run_alone(self, step: str, fn: Callable[..., Any], *args: Any) -> None:
        """Become busy and run one job that is no step of a chain (load, export)."""
        self._chain = []
        self._set_busy(True)
        self.launch(step, fn, *args)

    def launch(self, step: str, fn: Callable[..., Any], *args: Any) -> None:
        """Run ``fn(*args, reporter)`` as ``step``'s job (in the engine process
        for the engine's steps); its result goes to the host."""
        self._what = f"{steps.plain_label(step)} in the main window"
        if step in ENGINE_STEPS:  # their GIL would stall the window
            fn = engine_process.in_engine(fn, step not in steps.UNSTOPPABLE, self._what)
        self.job = workers.run_stage(
            fn,
            *args,
            name=step,
            on_result=lambda payload: self._on_returned(step, payload),
            on_error=lambda exc: self._on_errored(step, exc),
            on_progress=self._host.emit_progress,
        )
        self._host.emit_started(step)

    def stop(self) -> None:
        """Drop the rest of the chain and become idle (a step refused to start)."""
        self._chain = []
        self._set_busy(False)

    def cancel(self) -> None:
        """Ask the running job to stop; the steps after it are dropped."""
        if self.job is not None:
            self._chain_dropped = bool(self._chain)
            self._chain = []
            self.job.cancel()

    def shutdown(self, timeout_s: float) -> bool:
        """Drop the running job and wait for the worker threads (window closing)."""
        self._closing = True
        self._chain = []
        if self.job is not None:
            self.job.discard()
            self.job = None
        self._busy = False
        return workers.wait_for_workers(timeout_s)

    def _start_next(self) -> None:
        self._host.start_step(self._chain.pop(0))

    def _set_busy(self, busy: bool) -> None:
        self._busy = busy
        if not self._closing:
            self._host.emit_busy(busy)

    def _on_returned(self, step: str, payload: tuple) -> None:
        result, seconds = payload
        self.job = None
        if step == "load":  # its imports run while the user looks at the scans
            engine_process.ENGINE.start()
        emit = self._host.step_returned(step, result, seconds)
        if step == "load":  # the old scans are dropped: the engine lets go too
            engine_process.ENGINE.trim()
        if self._chain:
            emit()
            self._start_next()
            return
        self._set_busy(False)
        emit()
        if self._chain_dropped:
            self._chain_dropped = False
            self._host.emit_chain_dropped(step)

    def _on_errored(self, step: str, exc: BaseException) -> None:
        self.job = None
        self._chain = []
        self._chain_dropped = False
        self._set_busy(False)
        self._host.step_failed(step, exc)
