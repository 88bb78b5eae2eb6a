"""The one place that runs work off the GUI thread.

``run_stage(fn, *args, on_result=..., on_progress=..., on_error=...)`` calls
``fn(*args, reporter)`` in superqt's thread pool and returns a :class:`StageJob`.
The reporter is an :class:`amrst.progress.EventReporter`: ``cancel()`` sets its
``threading.Event`` and the work raises ``Cancelled`` at its next check point.

The app's concurrency model: the heavy computation (every engine step, a scan's
description, export) runs in the engine process (``engine_process``), so a worker
thread here only waits on that process, reads a file, or prepares a view's arrays
from at most the points it displays (picking, colouring, stem slices, the overlay's
distances). Results are plain data (engine objects and numpy arrays); VTK objects
are made, changed and dropped on the GUI thread only. Jobs started with
``display=True`` (the views' scenes and slices) run one at a time, as napari's
slicer does: they never compete with each other for the GIL.

A cancelled job keeps nothing of its own result: once ``cancel()`` was called, a
value the work still returns arrives as ``errored(Cancelled())``, so Cancel always
means "drop this step". And Cancel answers within ``CANCEL_GRACE_S`` at any size:
if the work has not reached a check point by then (one numpy call on millions of
points can take seconds), the job ends as cancelled at once and the worker thread,
already told to stop, ends at its next check point with nothing delivered
(``ended`` is emitted then).

Every callback runs on the GUI thread: the worker's signals are relayed through a
``StageJob`` (a QObject created on the GUI thread) with queued connections.
"""

from __future__ import annotations

import contextlib
import logging
import traceback
import warnings
from collections import deque
from typing import TYPE_CHECKING, Any

from PySide6.QtCore import QObject, Qt, QThreadPool, QTimer, Signal, Slot
from superqt.utils import WorkerBase, create_worker

from amrst.errors import Cancelled
from amrst.progress import EventReporter

if TYPE_CHECKING:
    from collections.abc import Callable

log = logging.getLogger("amrst_gui.workers")

# After Cancel, the longest wait for the work's next check point before the job is
# reported cancelled anyway.
CANCEL_GRACE_S = 0.5


class StageJob(QObject):
    """A running stage: progress, result and error arrive as GUI-thread signals.

    Emits ``progressed(float, str)``, ``returned(object)``, ``errored(object)``
    (the exception; its ``__traceback_text__`` attribute holds the worker
    traceback) and ``finished()`` once, after either of the two; then ``ended()``
    once the worker thread itself is over (for a job cancelled before its next check
    point, later than ``finished``).
    """

    progressed = Signal(float, str)
    returned = Signal(object)
    errored = Signal(object)
    finished = Signal()
    ended = Signal()
    _progress_from_worker = Signal(float, str)

    def __init__(self, name: str, parent: QObject | None = None) -> None:
        super().__init__(parent)
        self.name = name
        self.reporter = EventReporter(on_progress=self._progress_from_worker.emit)
        self._worker: WorkerBase | None = None
        self._done = False
        self._discarded = False
        self._abandon_timer: QTimer | None = None
        # Emitted from the worker thread, delivered on this object's (GUI) thread.
        self._progress_from_worker.connect(
            self._relay_progress, Qt.ConnectionType.QueuedConnection
        )

    @property
    def done(self) -> bool:
        """True once the work returned or raised."""
        return self._done

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

    def _start(self, fn: Callable[..., Any], args: tuple, kwargs: dict) -> None:
        # The work must not hold the job: if the worker thread dropped the last
        # reference, the job (a QObject with a live QTimer after Cancel) would be
        # deleted in the worker thread and its timer would fire on freed memory.
        reporter = self.reporter

        def work() -> Any:
            try:
                return fn(*args, reporter, **kwargs)
            except BaseException as exc:
                # Keep the worker traceback for the log; the exception crosses
                # threads (one from the engine process brings its own).
                if not hasattr(exc, "__traceback_text__"):
                    exc.__traceback_text__ = traceback.format_exc()  # type: ignore[attr-defined]
                raise

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
    def _relay_returned(self, result: object) -> None:
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
        a cycle only Python's cyclic GC frees, in whatever thread it happens to
        run, and a job deleted in a worker thread with an active Cancel timer
        crashes Qt's timer list. So the timer stops here and the connections go,
        on the GUI thread.
        """
        self._stop_abandon_timer()
        _DISPLAY_TURNS.ended(self)
        self.ended.emit()
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            signals = (self.progressed, self.returned, self.errored, self.finished)
            for signal in (*signals, self.ended):
                with contextlib.suppress(RuntimeError, TypeError):
                    signal.disconnect()
        _LIVE.discard(self)

    def _end_unstarted(self, exc: BaseException | None = None) -> None:
        """End a job whose worker never started: cancelled (or ``exc``), nothing
        run."""
        self._finish(self.errored, Cancelled() if exc is None else exc)
        self._release()

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


def run_stage(
    fn: Callable[..., Any],
    *args: Any,
    name: str = "",
    on_result: Callable[[Any], None] | None = None,
    on_progress: Callable[[float, str], None] | None = None,
    on_error: Callable[[BaseException], None] | None = None,
    on_finished: Callable[[], None] | None = None,
    display: bool = False,
    **kwargs: Any,
) -> StageJob:
    """Run ``fn(*args, reporter, **kwargs)`` in a worker thread.

    Parameters
    ----------
    fn : callable
        Its last positional argument is the reporter. It returns plain data:
        never a VTK object.
    name : str
        A label for log messages.
    on_result, on_progress, on_error, on_finished : callables
        Called on the GUI thread with the return value, ``(fraction, message)``,
        the exception, and nothing, respectively.
    display : bool
        A view's job: it runs after the display jobs started before it, one at a
        time (a job dropped meanwhile ends at its turn, without running).

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
    if display:
        _DISPLAY_TURNS.add(job, lambda: job._start(fn, args, kwargs))
    else:
        job._start(fn, args, kwargs)
    return job


_LIVE: set[StageJob] = set()


class _Turns:
    """Display jobs run one at a time, in the order they were started (napari's
    slicer does the same): they never compete with each other for the GIL.

    Kept on the GUI thread: a job waiting for its turn holds no worker thread, and
    one dropped while it waits ends without running.
    """

    def __init__(self) -> None:
        self._running: StageJob | None = None
        self._waiting: deque[tuple[StageJob, Callable[[], None]]] = deque()

    def add(self, job: StageJob, start: Callable[[], None]) -> None:
        self._waiting.append((job, start))
        if self._running is None:
            self._next()

    def ended(self, job: StageJob) -> None:
        if job is self._running:
            self._running = None
            self._next()

    def drop_waiting(self) -> None:
        """End every job still waiting for its turn, unstarted (the app closes)."""
        while self._waiting:
            self._waiting.popleft()[0]._end_unstarted()

    def _next(self) -> None:
        while self._waiting and self._running is None:
            job, start = self._waiting.popleft()
            if job.reporter.cancelled:
                job._end_unstarted()  # its handlers may start the next one
                continue
            self._running = job
            try:
                start()
            except Exception as exc:  # no worker thread: the turn passes on
                self._running = None
                job._end_unstarted(exc)


_DISPLAY_TURNS = _Turns()


# Jobs that may run at once: a step, a description, a view's job, the Plot window's
# and the Campaign dock's. Qt's default (one thread per core) would queue a view's
# job behind a step.
MIN_THREADS = 8


def _enough_threads() -> None:
    pool = QThreadPool.globalInstance()
    if pool.maxThreadCount() < MIN_THREADS:
        pool.setMaxThreadCount(MIN_THREADS)


def wait_for_workers(timeout_s: float = 60.0) -> bool:
    """Block until every worker thread has returned; True if they all did in time.

    Used when the window closes: cancel first, then wait (napari's pattern), so
    no worker outlives the widgets its results were meant for. Display jobs still
    waiting for their turn end unstarted.
    """
    _DISPLAY_TURNS.drop_waiting()
    return QThreadPool.globalInstance().waitForDone(int(timeout_s * 1000))
