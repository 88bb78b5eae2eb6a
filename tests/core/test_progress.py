"""Reporters: sub-ranges; the two scans of a pair reporting in turn."""

from __future__ import annotations

import pytest

from amrst.errors import Cancelled
from amrst.progress import EventReporter, SubReporter


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


def test_both_scans_returns_both_in_order_and_raises_the_target_error_first() -> None:
    from amrst.pipeline import both_scans

    assert both_scans(lambda item, rep: item * 2, 1, 2) == (2, 4)

    def fail(item, rep):
        raise KeyError(item)

    with pytest.raises(KeyError, match="target"):
        both_scans(fail, "target", "source")


def test_both_scans_report_in_turn_on_their_halves() -> None:
    from amrst.pipeline import both_scans

    parent, seen = _recording()

    def work(item, rep):
        rep.progress(0.5, "thinned")
        rep.progress(1.0)
        return item

    assert both_scans(work, "t", "s", parent) == ("t", "s")
    assert seen == [
        (0.25, "target: thinned"),
        (0.5, "target"),
        (0.75, "source: thinned"),
        (1.0, "source"),
    ]
    parent.cancel()
    with pytest.raises(Cancelled):
        both_scans(lambda item, rep: rep.check_cancelled(), "t", "s", parent)
