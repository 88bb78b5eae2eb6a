"""workers.run_stage: Cancel answers within a second and drops the step's result."""

from __future__ import annotations

import time

from amrst.errors import Cancelled
from amrst_gui import workers


def _run(fn, qtbot):
    got: dict = {"result": [], "error": []}
    job = workers.run_stage(
        fn,
        on_result=got["result"].append,
        on_error=got["error"].append,
    )
    return job, got


def test_cancel_without_a_check_point_answers_within_the_grace_time(qtbot):
    """Work that never checks (one long library call) is reported cancelled after
    CANCEL_GRACE_S; its late result is never delivered."""

    def long_call(reporter):
        time.sleep(2.0)
        return "late"

    job, got = _run(long_call, qtbot)
    qtbot.wait(100)
    start = time.perf_counter()
    job.cancel()
    qtbot.waitUntil(lambda: bool(got["error"]), timeout=5_000)
    assert time.perf_counter() - start < workers.CANCEL_GRACE_S + 0.5
    assert isinstance(got["error"][0], Cancelled)
    assert not job.worker_done.is_set()  # the thread is still in its call ...
    qtbot.waitUntil(job.worker_done.is_set, timeout=10_000)
    qtbot.wait(100)  # ... and what it returned then is dropped
    assert got["result"] == []
    assert len(got["error"]) == 1


def test_a_result_returned_after_cancel_is_dropped(qtbot):
    """The work passed its last check point before Cancel and returned anyway:
    the step keeps nothing (this Fine result used to be kept)."""

    def finishes(reporter):
        reporter.progress(1.0, "done")
        return "result"

    job, got = _run(finishes, qtbot)
    # Wait without turning the event loop, so the result is still queued.
    assert job.worker_done.wait(5.0)
    job.cancel()  # before the queued result reached the GUI thread
    qtbot.waitUntil(lambda: bool(got["error"]), timeout=5_000)
    assert got["result"] == []
    assert isinstance(got["error"][0], Cancelled)


def test_a_job_not_cancelled_delivers_its_result(qtbot):
    job, got = _run(lambda reporter: 7, qtbot)
    qtbot.waitUntil(lambda: bool(got["result"]), timeout=5_000)
    assert got == {"result": [7], "error": []}
    assert job.done


def test_a_finished_job_is_freed_by_reference_counting_on_the_gui_thread(
    qtbot,
) -> None:
    """A StageJob and its worker's closure referred to each other: only Python's
    cyclic GC freed them, in whatever thread it ran, and a job deleted in a worker
    thread left its Cancel timer registered on the GUI thread (a segfault in
    QTimerInfoList::activateTimers, about one GUI test run in three)."""
    import gc
    import threading
    import weakref

    from amrst_gui import workers

    gate = threading.Event()
    got: list = []
    deleted_on: list = []

    def fn(reporter):
        gate.wait(5)
        return "done"

    gc.disable()  # no cyclic GC: only reference counting may free the job
    try:
        job = workers.run_stage(fn, on_result=got.append)
        job.cancel()  # arms the abandon timer, the QTimer that outlived its job
        job.destroyed.connect(lambda *_: deleted_on.append(threading.get_ident()))
        ref = weakref.ref(job)
        del job
        assert ref() is not None, "the job went while its worker still ran"
        gate.set()
        qtbot.waitUntil(lambda: ref() is None, timeout=10_000)
        qtbot.waitUntil(lambda: bool(deleted_on), timeout=5_000)
    finally:
        gc.enable()
    assert deleted_on == [threading.main_thread().ident]


def _held_result(qtbot):
    """A job whose result reached the GUI thread within DRAW_GAP_MS of a frame:
    (job, got, the moment the frame ended)."""
    from amrst_gui.pacing import PACE

    job, got = _run(lambda reporter: 7, qtbot)
    assert job.worker_done.wait(5.0)
    time.sleep(0.1)  # superqt posts the result: queued, the event loop not turned
    PACE.mark()  # a view's frame ends ...
    frame_end = time.perf_counter()
    return job, got, frame_end


def test_a_result_right_after_a_frame_is_applied_a_turn_later(qtbot):
    """Issue 15: a step's result applied in the same turn of the event loop as a
    view's frame made one stall of both (after Match: 0.1-0.15 s)."""
    from amrst_gui.pacing import DRAW_GAP_MS

    job, got, frame_end = _held_result(qtbot)
    delivered: list[float] = []
    job.returned.connect(lambda _r: delivered.append(time.perf_counter()))
    qtbot.waitUntil(lambda: bool(got["result"]), timeout=5_000)
    assert got == {"result": [7], "error": []}
    assert delivered[0] - frame_end >= DRAW_GAP_MS / 1000 * 0.9
    assert job.done


def test_a_held_result_is_dropped_by_cancel_and_the_job_lives_until_then(qtbot):
    import weakref

    job, got, _ = _held_result(qtbot)
    qtbot.waitUntil(lambda j=job: j._held is not None, timeout=5_000)
    job.cancel()  # while the result waits for its turn
    ref = weakref.ref(job)
    del job
    qtbot.waitUntil(lambda: bool(got["error"]), timeout=5_000)
    assert got["result"] == []
    assert isinstance(got["error"][0], Cancelled)
    qtbot.waitUntil(lambda: ref() is None, timeout=5_000)  # released after it


def test_worker_threads_run_below_the_window_s_priority(qtbot):
    """Linux: the pool's threads are niced like the engine process, so the GUI
    thread gets a core first when a result arrives."""
    import os
    import sys
    import threading

    import pytest

    if not sys.platform.startswith("linux"):
        pytest.skip("per-thread niceness is Linux's")

    from amrst_gui.pacing import BACKGROUND_NICE

    def niceness(reporter):
        return os.getpriority(os.PRIO_PROCESS, threading.get_native_id())

    _job, got = _run(niceness, qtbot)
    qtbot.waitUntil(lambda: bool(got["result"]), timeout=5_000)
    assert got["result"][0] >= BACKGROUND_NICE
    assert os.getpriority(os.PRIO_PROCESS, threading.get_native_id()) < (
        BACKGROUND_NICE
    )
