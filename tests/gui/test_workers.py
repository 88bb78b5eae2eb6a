"""workers.run_stage: Cancel answers before the work ends and drops the step's
result; display jobs take turns."""

from __future__ import annotations

import threading

from PySide6.QtCore import QThreadPool

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

    release = threading.Event()

    def long_call(reporter):
        release.wait(30)
        return "late"

    job, got = _run(long_call, qtbot)
    ended: list[bool] = []
    job.ended.connect(lambda: ended.append(True))  # once the worker thread is over
    qtbot.wait(100)
    job.cancel()
    try:
        qtbot.waitUntil(lambda: bool(got["error"]), timeout=60_000)
        assert isinstance(got["error"][0], Cancelled)
        assert ended == []  # the thread is still in its call: not ended
    finally:
        release.set()
    qtbot.waitUntil(lambda: bool(ended), timeout=60_000)
    assert ended == [True]  # ended once, when the thread was over
    qtbot.wait(100)  # ... and what it returned then is dropped
    assert got["result"] == []
    assert len(got["error"]) == 1


def test_a_result_returned_after_cancel_is_dropped(qtbot):
    """The work passed its last check point before Cancel and returned anyway:
    the step keeps nothing, not even a finished Fine result."""

    def finishes(reporter):
        reporter.progress(1.0, "done")
        return "result"

    job, got = _run(finishes, qtbot)
    # Wait for the thread to return without turning the event loop, so the result
    # is still queued.
    assert QThreadPool.globalInstance().waitForDone(5000)
    job.cancel()  # before the queued result reached the GUI thread
    qtbot.waitUntil(lambda: bool(got["error"]), timeout=60_000)
    assert got["result"] == []
    assert isinstance(got["error"][0], Cancelled)


def test_a_job_not_cancelled_delivers_its_result(qtbot):
    job, got = _run(lambda reporter: 7, qtbot)
    qtbot.waitUntil(lambda: bool(got["result"]), timeout=60_000)
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
        qtbot.waitUntil(lambda: ref() is None, timeout=60_000)
        qtbot.waitUntil(lambda: bool(deleted_on), timeout=60_000)
    finally:
        gc.enable()
    assert deleted_on == [threading.main_thread().ident]


def test_display_jobs_take_turns_and_a_dropped_one_never_runs(qtbot):
    """The views' jobs run one at a time, in order; one discarded while it
    waits for its turn ends without calling its function."""
    gate = threading.Event()
    running: list[str] = []
    overlap: list[bool] = []
    calls: list[str] = []

    def job_fn(name):
        def fn(reporter):
            overlap.append(bool(running))
            running.append(name)
            calls.append(name)
            if name == "first":
                gate.wait(30)
            running.remove(name)
            return name

        return fn

    # The work earlier tests left ending must be over first: three threads of the pool
    # are needed at once, and a display job of theirs would take its turn among ours.
    assert workers.wait_for_workers(60.0)
    got: list[str] = []
    first = workers.run_stage(job_fn("first"), display=True, on_result=got.append)
    # Deadlines, not timings: a loaded machine may take seconds to start a thread.
    qtbot.waitUntil(lambda: calls == ["first"], timeout=60_000)
    dropped = workers.run_stage(job_fn("dropped"), display=True, on_result=got.append)
    last = workers.run_stage(job_fn("last"), display=True, on_result=got.append)
    qtbot.wait(200)
    assert calls == ["first"]  # the others wait for its end...
    # ... on the GUI thread: a job waiting for its turn holds no worker thread.
    assert QThreadPool.globalInstance().activeThreadCount() == 1
    dropped.discard()
    gate.set()
    # They ran in turn, and the next starts once the one before it delivered.
    qtbot.waitUntil(lambda: got == ["first", "last"], timeout=60_000)
    assert calls == ["first", "last"]
    assert not any(overlap)
    assert first.done
    assert last.done
    assert dropped.done  # ended at its turn, without running


def test_closing_ends_the_display_jobs_still_waiting_for_their_turn(qtbot):
    """wait_for_workers (the window closing) starts no waiting view job later."""
    gate = threading.Event()
    calls: list[str] = []

    def fn(name):
        def run(reporter):
            calls.append(name)
            gate.wait(30)

        return run

    assert workers.wait_for_workers(60.0)
    running = workers.run_stage(fn("running"), display=True)
    waiting = workers.run_stage(fn("waiting"), display=True)
    qtbot.waitUntil(lambda: calls == ["running"], timeout=60_000)
    running.discard()
    assert not workers.wait_for_workers(0.2)  # the running one is still at work
    assert waiting.done  # ended, never to start
    gate.set()
    assert workers.wait_for_workers(60.0)
    qtbot.wait(100)  # the running job's end reaches the GUI thread: nothing starts
    assert calls == ["running"]
