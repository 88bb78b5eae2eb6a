"""Reporters: sub-ranges, and several tasks reporting at once."""

from __future__ import annotations

import itertools
import threading

import pytest

from amrst.errors import Cancelled
from amrst.progress import EventReporter, SharedReporter, SubReporter


def _recording():
    seen: list[tuple[float, str]] = []
    return EventReporter(lambda f, m: seen.append((f, m))), seen


def test_sub_reporter_names_its_stage_once() -> None:
    parent, seen = _recording()
    sub = SubReporter(parent, 0.5, 1.0, "preprocess")
    sub.progress(0.5, "thinned")
    sub.progress(1.0, "preprocess: done")
    sub.progress(1.0)
    assert seen == [
        (0.75, "preprocess: thinned"),
        (1.0, "preprocess: done"),
        (1.0, "preprocess"),
    ]


def test_shared_reporter_sums_interleaved_tasks_monotonically() -> None:
    parent, seen = _recording()
    shared = SharedReporter(parent, 2, 0.2, 0.6)
    a, b = shared.task(0, "target"), shared.task(1, "source")
    a.progress(0.5, "half")
    b.progress(1.0, "all")
    a.progress(0.3, "late")  # an out-of-order report never moves the sum back
    a.progress(1.0)
    fractions = [f for f, _ in seen]
    assert fractions == pytest.approx([0.3, 0.5, 0.5, 0.6])
    assert seen[0][1] == "target: half"
    assert seen[-1][1] == "target"


def test_shared_reporter_from_threads_stays_monotonic() -> None:
    parent, seen = _recording()
    shared = SharedReporter(parent, 2)

    def work(i: int) -> None:
        rep = shared.task(i)
        for k in range(1, 201):
            rep.progress(k / 200)

    threads = [threading.Thread(target=work, args=(i,)) for i in range(2)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    fractions = [f for f, _ in seen]
    assert all(b >= a for a, b in itertools.pairwise(fractions))
    assert fractions[-1] == pytest.approx(1.0)


def test_shared_reporter_passes_cancel_on() -> None:
    parent, _ = _recording()
    parent.cancel()
    with pytest.raises(Cancelled):
        SharedReporter(parent, 2).task(1).check_cancelled()


def test_both_scans_stops_the_sibling_when_one_fails() -> None:
    import time

    from amrst.pipeline import both_scans

    laps = []

    def work(item, rep):
        if item == "bad":
            time.sleep(0.05)
            raise ValueError("source is corrupt")
        for k in range(2000):  # 20 s if nobody stops it
            rep.check_cancelled()
            laps.append(k)
            time.sleep(0.01)
        return item

    with pytest.raises(ValueError, match="corrupt"):
        both_scans(work, "good", "bad")
    assert len(laps) < 1000


def test_both_scans_returns_both_in_order_and_raises_the_target_error_first() -> None:
    from amrst.pipeline import both_scans

    assert both_scans(lambda item, rep: item * 2, 1, 2) == (2, 4)

    def fail(item, rep):
        raise KeyError(item)

    with pytest.raises(KeyError, match="target"):
        both_scans(fail, "target", "source")
