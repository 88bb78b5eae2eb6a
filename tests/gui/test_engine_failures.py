"""The engine process when things go wrong: an engine error, a job's
own OSError, a call it cannot read or cannot be sent, an engine killed mid-step,
Cancel on a job that may not stop. Each arrives as it would in the app's own
thread, with a fresh engine where the old one can no longer be trusted.

No Qt here: the engine process and its messages are plain Python.
"""

from __future__ import annotations

import io
import os
import threading
import time

import numpy as np
import pytest

from amrst.errors import Cancelled
from amrst.progress import NULL_REPORTER, EventReporter


def test_an_engine_error_arrives_as_it_would_in_the_app(tmp_path):
    from amrst.errors import AmrstError
    from amrst_gui import jobs
    from amrst_gui.engine_process import EngineProcess

    bad = tmp_path / "scan.las"
    bad.write_bytes(b"not a las file at all")
    engine = EngineProcess()
    try:
        with pytest.raises(AmrstError) as there:
            engine.call(jobs.load_pair, {"target": bad}, reporter=NULL_REPORTER)
    finally:
        engine.stop()
    with pytest.raises(AmrstError) as here:
        jobs.load_pair({"target": bad}, NULL_REPORTER)
    assert str(there.value) == str(here.value)
    assert type(there.value) is type(here.value)
    assert "load_pair" in there.value.__traceback_text__  # the engine's traceback


def test_what_cannot_be_sent_is_refused_and_the_next_call_still_works(sample_clouds):
    """A call whose arguments do not pickle (a lambda) raises in the app and
    sends nothing; an array it gave a token to is sent whole the next time."""
    import pickle

    from amrst.params import RegistrationParams
    from amrst_gui import jobs, wire
    from amrst_gui.engine_process import EngineProcess

    app = wire.ArrayCache(weak=True, first_token=0)
    big = np.zeros((100_000, 3))
    refused = (pickle.PicklingError, AttributeError, TypeError)
    with pytest.raises(refused):
        wire.write_message(io.BytesIO(), {"a": big, "f": lambda: 0}, app)
    assert app.token_of(big) is None
    engine = EngineProcess()
    try:
        with pytest.raises(refused):
            engine.call(
                jobs.separate_pair, {"f": lambda: 0}, None, reporter=NULL_REPORTER
            )
        out, _ = engine.call(
            jobs.separate_pair,
            sample_clouds,
            RegistrationParams(),
            reporter=NULL_REPORTER,
        )
        assert out["target"].is_wood.any()
    finally:
        engine.stop()


@pytest.mark.slow
def test_an_engine_that_dies_mid_step_is_reported_and_replaced(big_clouds):
    """Out of memory, the system kills the biggest process: the step fails with a
    message that says what to do, and the next step starts a fresh engine."""
    import signal

    from amrst.errors import AmrstError
    from amrst.params import RegistrationParams
    from amrst_gui import jobs
    from amrst_gui.engine_process import EngineProcess

    engine = EngineProcess()
    engine.start()
    first = engine.pid

    def kill_soon() -> None:
        time.sleep(1.0)
        if engine.pid is not None:
            os.kill(engine.pid, signal.SIGKILL)

    threading.Thread(target=kill_soon).start()
    try:
        with pytest.raises(
            AmrstError, match=r"engine process stopped \(killed by signal 9\)"
        ):
            engine.call(
                jobs.separate_pair,
                big_clouds,
                RegistrationParams(),
                reporter=NULL_REPORTER,
            )
        small = {k: c.select(np.arange(0, len(c), 200)) for k, c in big_clouds.items()}
        analyses, _ = engine.call(
            jobs.separate_pair, small, RegistrationParams(), reporter=NULL_REPORTER
        )
        assert engine.pid not in (None, first)
        assert analyses["source"].is_wood.any()
    finally:
        engine.stop()


def test_a_call_the_engine_cannot_read_restarts_it_and_the_arrays_cross_again(
    sample_clouds,
):
    """The engine cannot import a function of this test module: it says so and
    ends; the app starts a fresh engine, which gets every array whole."""
    from amrst.params import RegistrationParams
    from amrst_gui import jobs
    from amrst_gui.engine_process import EngineProcess

    engine = EngineProcess()
    clouds = dict(sample_clouds)
    big = {"target": clouds["target"], "extra": np.zeros((200_000, 3))}
    try:
        with pytest.raises(Exception, match="test_engine_failures"):
            engine.call(_not_importable_there, big, reporter=NULL_REPORTER)
        assert engine.pid is None  # ended with the message it could not read
        out, _ = engine.call(
            jobs.separate_pair, clouds, RegistrationParams(), reporter=NULL_REPORTER
        )
        assert out["target"].is_wood.any()
    finally:
        engine.stop()


def _not_importable_there(items, reporter):
    return len(items)


def test_a_jobs_own_os_error_arrives_as_itself_and_the_engine_lives_on():
    """An OSError of the job (a folder gone while exporting) is the job's error,
    not a dead engine."""
    from amrst_gui.engine_process import EngineProcess

    engine = EngineProcess()
    try:
        with pytest.raises(FileNotFoundError):
            engine.call(np.load, "/nonexistent/amrst/x.npy", reporter=NULL_REPORTER)
        pid = engine.pid
        assert pid is not None
        with pytest.raises(FileNotFoundError):
            engine.call(np.load, "/nonexistent/amrst/y.npy", reporter=NULL_REPORTER)
        assert engine.pid == pid
    finally:
        engine.stop()


def test_a_call_that_may_not_stop_runs_to_its_end_after_cancel(sample_clouds):
    """Export writes files: Cancel (or closing the window) lets it finish."""
    from amrst.params import RegistrationParams
    from amrst_gui import jobs
    from amrst_gui.engine_process import EngineProcess

    reporter = EventReporter()
    reporter.cancel()
    engine = EngineProcess()
    try:
        out, _ = engine.call(
            jobs.separate_pair,
            sample_clouds,
            RegistrationParams(),
            reporter=reporter,
            stoppable=False,
        )
        assert out["target"].is_wood.any()
        with pytest.raises(Cancelled):
            engine.call(
                jobs.separate_pair,
                sample_clouds,
                RegistrationParams(),
                reporter=reporter,
            )
    finally:
        engine.stop()
