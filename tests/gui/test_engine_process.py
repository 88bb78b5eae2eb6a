"""The steps' engine process: the same results as in the app's own
threads, big arrays sent once, errors and Cancel as before, and a GUI thread that
keeps running while a step computes on millions of points.

No Qt here: the engine process and its messages are plain Python.
"""

from __future__ import annotations

import io
import os
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pytest

from amrst.errors import Cancelled
from amrst.progress import NULL_REPORTER, EventReporter


def _round_trip(obj, send, receive):
    from amrst_gui import wire

    pipe = io.BytesIO()
    wire.write_message(pipe, obj, send)
    size = pipe.tell()
    pipe.seek(0)
    return wire.read_message(pipe, receive), size


def test_a_big_array_crosses_once_and_comes_back_as_itself():
    from amrst.types import Cloud
    from amrst_gui import wire

    app = wire.ArrayCache(weak=True, first_token=0)
    engine = wire.ArrayCache(weak=False, first_token=1)
    xyz = np.random.default_rng(0).random((200_000, 3))
    cloud = Cloud(xyz, attributes={"intensity": np.arange(200_000.0)})
    there, size = _round_trip({"target": cloud}, app, engine)
    got = there["target"]
    assert size > xyz.nbytes
    np.testing.assert_array_equal(got.xyz, cloud.xyz)
    np.testing.assert_array_equal(got.attributes["intensity"], np.arange(200_000.0))
    assert not got.xyz.flags.writeable  # a Cloud's arrays stay read-only
    # Sent again, the cloud names its arrays: a few hundred bytes.
    again, size = _round_trip({"target": cloud}, app, engine)
    assert size < 2_000
    assert again["target"].xyz is got.xyz
    # What the engine sends back of them is the app's own array, not a copy; a
    # new array of the engine's crosses once too.
    made = np.ones(300_000)
    back, size = _round_trip((got.xyz, made), engine, app)
    assert back[0] is cloud.xyz
    assert size > made.nbytes
    assert _round_trip(made, engine, app)[1] < 2_000
    # Small arrays travel inside the message every time.
    small = np.arange(10.0)
    assert _round_trip(small, app, engine)[0] is not small


def test_the_app_keeps_arrays_weakly_and_lists_what_it_still_holds():
    from amrst_gui import wire

    app = wire.ArrayCache(weak=True, first_token=0)
    engine = wire.ArrayCache(weak=False, first_token=1)
    a, b = np.zeros(200_000), np.ones(200_000)
    _round_trip((a, b), app, engine)
    assert len(app.alive()) == 2
    del a
    held = app.alive()
    assert [arr is b for arr in held.values()] == [True]
    engine.keep_only(set(held))
    assert len(engine.alive()) == 1


def test_a_step_in_the_engine_process_gives_the_same_analyses(sample_clouds):
    from amrst.params import RegistrationParams
    from amrst_gui import jobs
    from amrst_gui.engine_process import EngineProcess

    engine = EngineProcess()
    clouds = dict(sample_clouds)
    params = RegistrationParams()
    try:
        here, _ = jobs.separate_pair(clouds, params, NULL_REPORTER)
        here, _ = jobs.skeletonise_pair(here, params, NULL_REPORTER)
        progress: list = []
        reporter = EventReporter(lambda f, m: progress.append(m))
        there, _ = engine.call(jobs.separate_pair, clouds, params, reporter=reporter)
        assert engine.pid not in (None, os.getpid())
        assert progress, "the engine process reports its progress"
        there, _ = engine.call(jobs.skeletonise_pair, there, params, reporter=reporter)
    finally:
        engine.stop()
    for role in ("target", "source"):
        a, b = here[role], there[role]
        np.testing.assert_array_equal(a.is_wood, b.is_wood)
        np.testing.assert_array_equal(a.keypoints.xyz, b.keypoints.xyz)
        np.testing.assert_array_equal(b.cloud.xyz, clouds[role].xyz)


@pytest.mark.slow
@pytest.mark.perf
def test_a_step_on_millions_of_points_leaves_the_gui_thread_free(big_clouds):
    """Separating wood from leaves on 2M + 2M points: in the engine process the
    app's threads only wait on a pipe, so the calling thread keeps running."""
    from _timing import longest_gap_while

    from amrst.params import RegistrationParams
    from amrst_gui import jobs
    from amrst_gui.engine_process import EngineProcess

    engine = EngineProcess()
    engine.start()
    try:
        longest, out = longest_gap_while(
            lambda: engine.call(
                jobs.separate_pair,
                big_clouds,
                RegistrationParams(),
                reporter=NULL_REPORTER,
            )
        )
    finally:
        engine.stop()
    assert not isinstance(out, BaseException), out
    analyses, _seconds = out
    assert analyses["target"].is_wood.any()
    assert longest < 0.1, f"the calling process stalled {longest:.2f} s"


@pytest.mark.slow
def test_cancel_kills_the_step_at_once_and_the_next_call_starts_afresh(big_clouds):
    from amrst.params import RegistrationParams
    from amrst_gui import jobs
    from amrst_gui.engine_process import EngineProcess

    engine = EngineProcess()
    reporter = EventReporter()

    def cancel_soon() -> None:
        time.sleep(0.5)  # the clouds are on their way or being separated
        reporter.cancel()

    threading.Thread(target=cancel_soon).start()
    engine.start()
    first = engine.pid
    try:
        with pytest.raises(Cancelled):
            engine.call(
                jobs.separate_pair, big_clouds, RegistrationParams(), reporter=reporter
            )
        assert engine.pid != first  # killed, not waited for; a fresh one imports
        small = {k: c.select(np.arange(0, len(c), 200)) for k, c in big_clouds.items()}
        analyses, _ = engine.call(
            jobs.separate_pair, small, RegistrationParams(), reporter=NULL_REPORTER
        )
        assert len(analyses["target"].is_wood) <= len(small["target"])
    finally:
        engine.stop()


def test_the_app_still_runs_steps_where_no_process_can_start(
    monkeypatch, sample_clouds
):
    """A frozen app has no interpreter for the engine process: the step runs in
    the calling thread, as before."""
    from amrst.params import RegistrationParams
    from amrst_gui import jobs
    from amrst_gui.engine_process import EngineProcess

    monkeypatch.setattr(sys, "frozen", True, raising=False)
    engine = EngineProcess()
    clouds = dict(sample_clouds)
    analyses, _ = engine.call(
        jobs.separate_pair, clouds, RegistrationParams(), reporter=NULL_REPORTER
    )
    assert engine.pid is None
    assert analyses["target"].is_wood.any()


def test_starting_the_engine_never_waits_for_a_running_call():
    """The GUI thread starts the engine when a pair loads; while another window's
    call holds the process, it returns at once instead of freezing the window."""
    from amrst_gui.engine_process import EngineProcess

    engine = EngineProcess()
    entered, leave = threading.Event(), threading.Event()

    def hold() -> None:
        with engine._lock:  # what a running call holds
            entered.set()
            leave.wait(30)

    holder = threading.Thread(target=hold)
    holder.start()
    try:
        assert entered.wait(10)
        starter = threading.Thread(target=engine.start)
        starter.start()
        starter.join(10)
        assert not starter.is_alive()  # returned while the lock was held
        assert engine.pid is None  # and left the process to the running call
    finally:
        leave.set()
        holder.join()
        engine.stop()


def test_a_call_not_stoppable_may_be_cancelled_while_it_waits_its_turn():
    """Export runs to its end once it runs; while it waits for another window's
    call, nothing was written yet and Cancel drops it."""
    from amrst_gui.engine_process import EngineProcess

    engine = EngineProcess()
    reporter = EventReporter()
    with engine._lock:  # another window's call
        threading.Timer(0.2, reporter.cancel).start()
        with pytest.raises(Cancelled):
            engine.call(np.array_equal, 1, reporter=reporter, stoppable=False)
    assert engine.pid is None  # it never reached the process
    assert not engine.serving("another job")


def test_the_engines_log_reaches_the_apps_loggers(sample_clouds, caplog):
    """The Log panel listens to the ``amrst`` loggers of the app's process: the
    engine's records are sent back and logged there."""
    import dataclasses
    import logging

    from amrst.params import RegistrationParams
    from amrst_gui import jobs
    from amrst_gui.engine_process import EngineProcess

    params = RegistrationParams()
    params = dataclasses.replace(
        params, preprocess=dataclasses.replace(params.preprocess, max_points=1000)
    )
    engine = EngineProcess()
    try:
        with caplog.at_level(logging.INFO, logger="amrst"):
            engine.call(
                jobs.separate_pair,
                sample_clouds,
                params,
                reporter=NULL_REPORTER,
            )
    finally:
        engine.stop()
    thinned = [r for r in caplog.records if "Large scan: thinned" in r.getMessage()]
    assert len(thinned) == 2  # one per scan
    assert thinned[0].levelno == logging.INFO
    assert thinned[0].name.startswith("amrst.")


def _engine_rss_mb(pid: int) -> float:
    status = Path(f"/proc/{pid}/status").read_text()
    return (
        next(int(ln.split()[1]) for ln in status.splitlines() if ln.startswith("VmRSS"))
        / 1024
    )


@pytest.mark.skipif(not Path("/proc/self/status").exists(), reason="needs /proc")
def test_the_engine_lets_go_of_what_the_app_dropped_when_told():
    """After a new pair is opened, the engine frees the old scans at once, not
    when the next step comes (then it held the old and the new together)."""
    from amrst_gui.engine_process import EngineProcess

    engine = EngineProcess()
    try:
        scan = np.random.default_rng(0).random((4_000_000, 3))  # 96 MB
        # Any call: the scan crosses and the engine keeps it.
        assert not engine.call(np.array_equal, scan, reporter=NULL_REPORTER)
        held = _engine_rss_mb(engine.pid)
        del scan
        engine.trim()
        time.sleep(1.0)
        assert _engine_rss_mb(engine.pid) < held - 60
    finally:
        engine.stop()
