"""The one place that runs work off the GUI thread (STYLE.md section 4).

``run_stage(fn, *args, on_result=..., on_progress=..., on_error=...)`` calls
``fn(*args, reporter)`` in superqt's thread pool and returns a :class:`StageJob`.
The reporter is an :class:`amrst.progress.EventReporter`: ``cancel()`` sets its
``threading.Event`` and the engine raises ``Cancelled`` at its next check point.

A cancelled job keeps nothing of its own result: once ``cancel()`` was called, a
value the work still returns (it passed its last check point before the request)
arrives as ``errored(Cancelled())``, so Cancel always means "drop this step". And
Cancel answers within ``CANCEL_GRACE_S`` at any size: if the work has not reached
a check point by then (one numpy call on millions of points can take seconds), the
job ends as cancelled at once and the worker thread, already told to stop, ends at
its next check point with nothing delivered (``worker_done`` is set then).

Every callback runs on the GUI thread: the worker's signals are relayed through a
``StageJob`` (a QObject created on the GUI thread) with explicit queued
connections, so no widget, plotter or session is ever touched from a worker.
"""

from __future__ import annotations

import contextlib
import logging
import threading
import traceback
import warnings
from typing import TYPE_CHECKING, Any

from PySide6.QtCore import QObject, Qt, QThreadPool, QTimer, Signal, Slot
from superqt.utils import WorkerBase, create_worker

from amrst.errors import Cancelled
from amrst.progress import EventReporter
from amrst_gui.pacing import LANES, PACE, at_least_nice
from amrst_gui.views.vtk_lock import release_later

if TYPE_CHECKING:
    from collections.abc import Callable

log = logging.getLogger("amrst_gui.workers")

# After Cancel, the longest wait for the work's next check point before the job is
# reported cancelled anyway (issue 15: Cancel within a second at any size).
CANCEL_GRACE_S = 0.5


class StageJob(QObject):
    """A running stage: progress, result and error arrive as GUI-thread signals.

    Emits ``progressed(float, str)``, ``returned(object)``, ``errored(object)``
    (the exception; its ``__traceback_text__`` attribute holds the worker
    traceback) and ``finished()`` once, after either of the two.
    """

    progressed = Signal(float, str)
    returned = Signal(object)
    errored = Signal(object)
    finished = Signal()
    _progress_from_worker = Signal(float, str)

    def __init__(self, name: str, parent: QObject | None = None) -> None:
        super().__init__(parent)
        self.name = name
        self.reporter = EventReporter(on_progress=self._progress_from_worker.emit)
        self._worker: WorkerBase | None = None
        self._done = False
        self._discarded = False
        self._abandon_timer: QTimer | None = None
        self._held: tuple[object] | None = None  # a result delivered a turn later
        self._release_after_delivery = False
        # Set when the worker thread itself has returned or raised.
        self.worker_done = threading.Event()
        # Emitted from the worker thread, delivered on this object's (GUI) thread.
        self._progress_from_worker.connect(
            self._relay_progress, Qt.ConnectionType.QueuedConnection
        )

    @property
    def done(self) -> bool:
        """True once the work returned or raised."""
        return self._done

    @property
    def cancel_requested(self) -> bool:
        """True once :meth:`cancel` was called."""
        return self.reporter.cancelled

    def cancel(self) -> None:
        """Ask the stage to stop at its next check point (does not wait); it is
        reported cancelled then, or after ``CANCEL_GRACE_S`` at the latest."""
        self.reporter.cancel()
        if not self._done and self._abandon_timer is None:
            self._abandon_timer = QTimer(self)
            self._abandon_timer.setSingleShot(True)
            self._abandon_timer.timeout.connect(self._abandon)
            self._abandon_timer.start(int(CANCEL_GRACE_S * 1000))

    def _abandon(self) -> None:
        if self._done:
            return
        log.info(
            "%s: no check point reached %.1f s after Cancel; the worker stops at its "
            "next one and its result is dropped",
            self.name,
            CANCEL_GRACE_S,
        )
        self._finish(self.errored, Cancelled())

    def discard(self) -> None:
        """Cancel, and drop every signal still on its way (used when closing)."""
        self._discarded = True
        self.cancel()

    def _start(
        self,
        fn: Callable[..., Any],
        args: tuple,
        kwargs: dict,
        lane: str | None = None,
    ) -> None:
        # The work must not hold the job: if the worker thread dropped the last
        # reference, the job (a QObject with a live QTimer after Cancel) would be
        # deleted in the worker thread and its timer would fire on freed memory
        # (a segfault in QTimerInfoList::activateTimers, about one GUI run in three).
        reporter, worker_done = self.reporter, self.worker_done

        def work() -> Any:
            # Niced like the engine process (pacing.BACKGROUND_NICE): with two
            # cores, a view's scene built here while the engine computed left the
            # GUI thread waiting 30-80 ms for a core when a step's result arrived
            # (issue 15). A thread cannot undo it without privileges, so the
            # pool's threads stay niced: they only ever run background work.
            at_least_nice()
            try:
                if lane is None:
                    return _Handed(fn(*args, reporter, **kwargs))
                with LANES.enter(lane, reporter):  # one job per lane at a time
                    reporter.check_cancelled()
                    return _Handed(fn(*args, reporter, **kwargs))
            except BaseException as exc:
                # Keep the worker traceback for the log; the exception crosses
                # threads (one from the engine process brings its own).
                if not hasattr(exc, "__traceback_text__"):
                    exc.__traceback_text__ = traceback.format_exc()  # type: ignore[attr-defined]
                raise
            finally:
                worker_done.set()

        worker = create_worker(work, _start_thread=False, _ignore_errors=True)
        worker.returned.connect(
            self._relay_returned, Qt.ConnectionType.QueuedConnection
        )
        worker.errored.connect(self._relay_errored, Qt.ConnectionType.QueuedConnection)
        worker.warned.connect(self._relay_warned, Qt.ConnectionType.QueuedConnection)
        # superqt's own "finished": the thread function is over, nothing more comes.
        worker.finished.connect(self._release, Qt.ConnectionType.QueuedConnection)
        self._worker = worker
        worker.start()

    @Slot(float, str)
    def _relay_progress(self, fraction: float, message: str) -> None:
        if not (self._discarded or self._done):
            self.progressed.emit(fraction, message)

    @Slot(object)
    def _relay_returned(self, handed: _Handed) -> None:
        result = handed.take()
        release_later(result)  # its last reference goes under VTK_LOCK
        wait = PACE.wait_ms()
        if wait and self._held is None and not self._done:
            # A view's frame just ended: the result is applied on a later turn of
            # the event loop, not in the same stall (after Match: a view's new
            # scene, then the match list, 0.1-0.15 s in one; issue 15).
            self._held = (result,)
            QTimer.singleShot(wait, self, self._deliver_held)
            return
        self._deliver(result)

    def _deliver_held(self) -> None:
        if self._held is None:
            return
        (result,), self._held = self._held, None
        self._deliver(result)
        if self._release_after_delivery:
            self._release()

    def _deliver(self, result: object) -> None:
        if self.reporter.cancelled:
            # Asked to stop: the step's result is dropped even if it got to the end.
            self._finish(self.errored, Cancelled())
            return
        self._finish(self.returned, result)

    @Slot(object)
    def _relay_errored(self, exc: object) -> None:
        self._finish(self.errored, exc)

    @Slot()
    def _release(self) -> None:
        """The worker thread is over (GUI thread): let go of everything it needed.

        Callers connect lambdas that hold the job (``lambda out: apply(job, out)``):
        a cycle only Python's cyclic GC frees, in whatever thread it happens to run.
        A job deleted in a worker thread while its Cancel timer was active left that
        timer registered on the GUI thread: a segfault in
        ``QTimerInfoList::activateTimers`` in a later test, about one run in three.
        So the timer stops here and the connections go, on the GUI thread.
        """
        if self._held is not None:  # the result is still to be delivered
            self._release_after_delivery = True
            return
        self._stop_abandon_timer()
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            for signal in (self.progressed, self.returned, self.errored, self.finished):
                with contextlib.suppress(RuntimeError, TypeError):
                    signal.disconnect()
        _LIVE.discard(self)

    def _stop_abandon_timer(self) -> None:
        if self._abandon_timer is not None:
            self._abandon_timer.stop()

    @Slot(tuple)
    def _relay_warned(self, warning: tuple) -> None:
        message, category = warning[0], warning[1]
        log.warning("%s: %s: %s", self.name, category.__name__, message)

    def _finish(self, signal: Any, value: object) -> None:
        if self._done:
            return
        self._done = True
        self._stop_abandon_timer()
        self._worker = None
        if self._discarded:
            return
        signal.emit(value)
        self.finished.emit()


class _Handed:
    """A worker's result on its way to the GUI thread, which takes it out.

    The worker thread lets go of the box, not of the result: whichever thread drops
    the box last, the result's last reference is the GUI thread's, and
    :func:`amrst_gui.views.vtk_lock.release_later` drops it under the VTK lock (a
    scene's VTK objects never die in a worker while another makes some).
    """

    __slots__ = ("_value",)

    def __init__(self, value: object) -> None:
        self._value: list[object] = [value]

    def take(self) -> object:
        return self._value.pop()


def run_stage(
    fn: Callable[..., Any],
    *args: Any,
    name: str = "",
    on_result: Callable[[Any], None] | None = None,
    on_progress: Callable[[float, str], None] | None = None,
    on_error: Callable[[BaseException], None] | None = None,
    on_finished: Callable[[], None] | None = None,
    lane: str | None = None,
    **kwargs: Any,
) -> StageJob:
    """Run ``fn(*args, reporter, **kwargs)`` in a worker thread.

    Parameters
    ----------
    fn : callable
        An engine function; its last positional argument is the reporter.
    name : str
        A label for log messages.
    on_result, on_progress, on_error, on_finished : callables
        Called on the GUI thread with the return value, ``(fraction, message)``,
        the exception, and nothing, respectively.
    lane : str, optional
        ``"display"`` or ``"describe"`` (see ``_Lanes``): the job waits until no
        other job of that lane runs (a job dropped meanwhile then ends at once).

    Returns
    -------
    StageJob
        ``cancel()`` asks the work to stop; signals carry the outcome.
    """
    _enough_threads()
    job = StageJob(name or getattr(fn, "__name__", "stage"))
    if on_progress is not None:
        job.progressed.connect(on_progress)
    if on_result is not None:
        job.returned.connect(on_result)
    if on_error is not None:
        job.errored.connect(on_error)
    if on_finished is not None:
        job.finished.connect(on_finished)
    # Held here until the work is over, released on the GUI thread: the caller may
    # drop its reference (a newer scene replaces an older one) while it runs.
    _LIVE.add(job)
    if lane is not None and lane not in LANES:
        raise ValueError(f"no lane {lane!r}")
    job._start(fn, args, kwargs, lane)
    return job


_LIVE: set[StageJob] = set()


# Jobs that may run at once: a step, the Scans dock's descriptions and the three
# views' scenes. Qt's default (one thread per core) queued the views behind a step.
MIN_THREADS = 8


def _enough_threads() -> None:
    pool = QThreadPool.globalInstance()
    if pool.maxThreadCount() < MIN_THREADS:
        pool.setMaxThreadCount(MIN_THREADS)
        # Idle threads stay: a new one cost 1.5 ms on the GUI thread at each start
        # after 30 s of quiet (Qt's expiry), four of them when a step's result
        # arrives (the next step and three views' scenes).
        pool.setExpiryTimeout(-1)


def wait_for_workers(timeout_s: float = 60.0) -> bool:
    """Block until every worker thread has returned; True if they all did in time.

    Used when the window closes: cancel first, then wait (napari's pattern), so
    no worker outlives the widgets its results were meant for.
    """
    return QThreadPool.globalInstance().waitForDone(int(timeout_s * 1000))
