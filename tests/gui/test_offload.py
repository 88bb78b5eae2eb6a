"""The Scans dock's spacing runs in a helper process (issue 15): the same answer as
``amrst.io.describe`` in this process, and Cancel stops it at once."""

from __future__ import annotations

import threading
import time

import numpy as np
import pytest

from amrst.errors import Cancelled
from amrst.io.describe import median_spacing
from amrst.progress import EventReporter
from amrst_gui import offload


def _cloud(n: int) -> np.ndarray:
    rng = np.random.default_rng(3)
    xyz = rng.random((n, 3)) * (4.0, 4.0, 12.0)
    xyz[:50] = xyz[50:100]  # identical points (distance 0) go along too
    return xyz


def test_the_helper_answers_as_describe_does():
    xyz = _cloud(300_000)
    helper = offload.Helper()
    try:
        assert helper.median_spacing(xyz, EventReporter()) == median_spacing(xyz)
        # float32 input, and a second request to the same helper
        xyz32 = xyz.astype(np.float32)
        assert helper.median_spacing(xyz32, EventReporter()) == median_spacing(xyz32)
    finally:
        helper.stop()


@pytest.mark.slow
def test_cancel_stops_the_helper_within_a_poll_and_the_next_request_works():
    xyz = _cloud(3_000_000)  # several seconds of work in the helper
    helper = offload.Helper()
    try:
        helper.start()
        reporter = EventReporter()
        marks: dict[str, float] = {}

        def cancel_soon() -> None:
            time.sleep(1.0)
            marks["cancel"] = time.perf_counter()
            reporter.cancel()

        threading.Thread(target=cancel_soon, daemon=True).start()
        with pytest.raises(Cancelled):
            helper.median_spacing(xyz, reporter)
        assert time.perf_counter() - marks["cancel"] < 0.5
        small = _cloud(20_000)
        assert helper.median_spacing(small, EventReporter()) == median_spacing(small)
    finally:
        helper.stop()


def test_a_helper_started_from_a_niced_worker_thread_is_nice_5_not_10():
    """Worker threads run at nice 5 (``pacing.BACKGROUND_NICE``) and a process
    inherits its starting thread's niceness: the helper's relative ``os.nice(5)``
    made it 10, behind the app's own background threads."""
    import os
    import sys

    from amrst_gui.pacing import BACKGROUND_NICE, at_least_nice

    if not sys.platform.startswith("linux"):
        pytest.skip("per-thread niceness is Linux's")
    helper = offload.Helper()
    seen: list[int] = []

    def in_a_worker() -> None:
        at_least_nice()
        helper.median_spacing(_cloud(1_000), EventReporter())  # starts it
        seen.append(os.getpriority(os.PRIO_PROCESS, helper._proc.pid))

    try:
        thread = threading.Thread(target=in_a_worker)
        thread.start()
        thread.join(60)
        assert seen == [BACKGROUND_NICE]
    finally:
        helper.stop()
