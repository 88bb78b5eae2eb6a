"""Real-scale app (issue 15): a big scan never stalls the window, the views draw
fewer points while the camera moves, and every step stops within a second of Cancel
keeping nothing of its own result.

The clouds are generated here (jittered copies of the bundled sample, seeded) and
written to a temporary folder: nothing big is shipped.
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))

from dense_clouds import write_dense_pair

BIG = 2_000_000
# Issue 15's target: no GUI-thread stall longer than 100 ms while a big scan loads.
# Before issue 15 loading this 2M + 2M pair stalled the window 13.8 s (describing
# both scans on the GUI thread, twice per scan, and building every view there);
# before this bound (49b2e3a) still 0.26-0.31 s on this 2-core machine at load
# average 4-5 (this test run on a copy of that commit): worker threads importing
# scipy on the first load, a scan's spacing computed in a worker thread, three
# views' scenes and two descriptions computing at once, first frames of 50,000
# points drawn back to back. Now 0.07-0.13 s at the same load; the margin over the
# 100 ms target is for a machine shared with other jobs.
MAX_STALL_S = 0.15


def _waited_for_a_core() -> float:
    """Seconds the calling thread has spent runnable but not running (Linux:
    the second field of /proc/thread-self/schedstat); 0.0 elsewhere."""
    try:
        with open("/proc/thread-self/schedstat") as f:
            return int(f.read().split()[1]) / 1e9
    except (OSError, IndexError, ValueError):
        return 0.0


class Watchdog:
    """A 10 ms QTimer on the GUI thread; ``max_gap_s``: its longest silence.

    ``max_app_gap_s``: the same without the time the GUI thread waited for a
    core the operating system gave to other programs (this machine is shared: a
    benchmark running beside the tests stretches every frame). What is left is
    the app's own doing: work on the GUI thread, or waiting for the GIL.
    """

    def __init__(self) -> None:
        from PySide6.QtCore import QTimer

        self.timer = QTimer()
        self.timer.setInterval(10)
        self.timer.timeout.connect(self._tick)
        self.last = time.perf_counter()
        self.queued = _waited_for_a_core()
        self.max_gap_s = 0.0
        self.max_app_gap_s = 0.0
        self.timer.start()

    def _tick(self) -> None:
        now, queued = time.perf_counter(), _waited_for_a_core()
        gap = now - self.last
        self.max_gap_s = max(self.max_gap_s, gap)
        self.max_app_gap_s = max(self.max_app_gap_s, gap - (queued - self.queued))
        self.last, self.queued = now, queued


@pytest.fixture(scope="module")
def big_pair(tmp_path_factory):
    return write_dense_pair(tmp_path_factory.mktemp("big"), BIG, BIG)


def _all_drawn(win) -> bool:
    views = win.scans_area.views()
    panes = [*win.scans_area.panes.values(), win.registration]
    return (
        all("points" in v.actor_names() for v in views)
        and "target_points" in win.registration.view.actor_names()
        and not any(getattr(p, "loader", None) and p.loader.pending for p in panes)
        and not win.session.busy
    )


def _load_big(make_main_window, qtbot, big_pair):
    from amrst_gui import workers

    # No earlier test's worker may still compute here (a cancelled step runs on
    # to its next check point): the watchdog measures this load only.
    assert workers.wait_for_workers(120)
    win = make_main_window()
    qtbot.wait(300)  # the window's first frames, as a user sees it open
    dog = Watchdog()
    start = time.perf_counter()
    win.open_pair(*big_pair)
    qtbot.waitUntil(lambda: _all_drawn(win), timeout=120_000)
    return win, dog, time.perf_counter() - start


@pytest.mark.slow
def test_a_big_scan_loads_without_stalling_the_window(
    make_main_window, qtbot, big_pair
):
    win, dog, seconds = _load_big(make_main_window, qtbot, big_pair)
    # The descriptions (bounds, spacing of 2M points) arrive later, off the GUI
    # thread too: the watchdog runs until both are shown.
    boxes = win.scans_panel.boxes.values()
    qtbot.waitUntil(
        lambda: all("median_spacing_m" in b.toolTip() for b in boxes), timeout=60_000
    )
    dog.timer.stop()
    print(f"longest GUI stall {dog.max_gap_s:.3f} s, load {seconds:.1f} s")
    assert dog.max_gap_s < MAX_STALL_S, (
        f"the GUI thread stalled {dog.max_gap_s:.2f} s (load took {seconds:.1f} s)"
    )
    view = win.scans_area.views()[0]
    shown = view.drawn_points()
    assert 0 < shown <= 200_000
    assert f"showing {shown:,} of {BIG:,} points" in view.caption()


RUN_ALL_POINTS = 4_000_000
# The target is 100 ms (docs/bench/app_speed.py measures it on a quiet machine);
# here 0.067-0.091 s with another benchmark running, and 0.14-0.33 s with the
# steps in a worker thread of the app (this test run on 7347d44).
RUN_ALL_MAX_STALL_S = 0.12


@pytest.fixture(scope="module")
def run_all_pair(tmp_path_factory):
    return write_dense_pair(tmp_path_factory.mktemp("runall"), *(RUN_ALL_POINTS,) * 2)


@pytest.mark.slow
def test_run_all_on_a_big_pair_never_stalls_the_window(
    make_main_window, qtbot, run_all_pair
):
    """Run all on 4M + 4M points, the window watched throughout. With the steps in
    a worker thread of the app their numpy calls held the GIL 0.1-0.17 s at a
    time on 2M points (the GUI thread idle, waiting). The steps run in the engine
    process now (amrst_gui.engine_process)."""
    win, _dog, _seconds = _load_big(make_main_window, qtbot, run_all_pair)
    s = win.session
    boxes = win.scans_panel.boxes.values()
    qtbot.waitUntil(
        lambda: all("median_spacing_m" in b.toolTip() for b in boxes), timeout=60_000
    )
    qtbot.wait(500)
    dog = Watchdog()
    start = time.perf_counter()
    s.run_all()
    qtbot.waitUntil(lambda: not s.busy, timeout=300_000)
    seconds = time.perf_counter() - start
    dog.timer.stop()
    assert s.fine is not None, "Run all did not get to Fine"
    print(
        f"Run all {seconds:.1f} s, longest GUI stall {dog.max_gap_s:.3f} s, "
        f"{dog.max_app_gap_s:.3f} s without waiting for a core"
    )
    assert dog.max_app_gap_s < RUN_ALL_MAX_STALL_S, (
        f"the GUI thread stalled {dog.max_app_gap_s:.2f} s during Run all "
        f"({dog.max_gap_s:.2f} s with the time it waited for a core)"
    )


@pytest.mark.slow
def test_the_views_draw_fewer_points_while_the_camera_moves(
    make_main_window, qtbot, big_pair
):
    from amrst_gui.views.scene import MOVING_POINTS

    win, _dog, _s = _load_big(make_main_window, qtbot, big_pair)
    view = win.scans_area.views()[0]
    qtbot.wait(500)  # the view steps its level of detail up while frames fit
    at_rest = view.drawn_points()
    iren = view.plotter.iren.interactor
    x, y = view.plotter.width() // 2, view.plotter.height() // 2
    iren.SetEventInformation(x, y, 0, 0)
    iren.LeftButtonPressEvent()
    iren.SetEventInformation(x + 20, y, 0, 0)
    iren.MouseMoveEvent()  # a rotation: the interactor style renders a frame
    assert view.moving
    assert view.drawn_points() <= min(MOVING_POINTS, at_rest)
    iren.LeftButtonReleaseEvent()
    assert not view.moving
    assert view.drawn_points() == at_rest  # the detail at rest comes back
    assert f"showing {at_rest:,} of {BIG:,} points" in view.caption()


def test_the_level_of_detail_fits_the_frame_budget():
    """The level drawn is the largest whose predicted frame fits the budget, and a
    view with no measured frame yet starts small and doubles per frame."""
    from amrst_gui.views import lod

    levels = lod.ladder(200_000)
    assert levels == (200_000, 100_000, 50_000, 25_000, 12_500)
    cost = lod.FrameCost()
    # Nothing measured: a small first frame.
    assert levels[lod.pick(levels, 0.06, None, cost=cost)] <= lod.START_POINTS
    cost.record(25_000, 0.005)  # 5 ms for 25,000 points
    # Up one level per frame (twice the points), although 200,000 would fit.
    assert levels[lod.pick(levels, 0.06, 25_000, cost=cost)] == 50_000
    assert levels[lod.pick(levels, 0.06, 100_000, cost=cost)] == 200_000
    # A slow frame: the level drops at once, below what the last frame drew.
    cost.record(200_000, 0.100)
    i = lod.pick(levels, 0.06, 200_000, cost=cost)
    assert cost.predict(levels[i]) <= 0.06 < cost.predict(levels[i - 1])
    # While moving: capped.
    cost.reset()
    cost.record(25_000, 0.001)
    assert levels[lod.pick(levels, 0.03, None, cap=30_000, cost=cost)] == 25_000
    # Never below the smallest level, even on a hopeless machine.
    cost.record(12_500, 10.0)
    assert lod.pick(levels, 0.06, 12_500, cost=cost) == len(levels) - 1


def test_each_layer_halves_at_each_level():
    from amrst_gui.views.layers import PointsLayer, Scene
    from amrst_gui.views.scene_jobs import MIN_SET_POINTS, prepare

    rng = np.random.default_rng(0)

    def layer(name, n):
        xyz = rng.random((n, 3)).astype(np.float32)
        return PointsLayer(name, (name,), xyz, np.zeros((n, 3), np.uint8))

    out = prepare(Scene(("t",), (layer("a", 150_000), layer("b", 50_000))))
    assert out.still["a"].n_points == 150_000
    assert out.still["b"].n_points == 50_000
    a = [p.n_points for p in out.sets["a"]]
    b = [p.n_points for p in out.sets["b"]]
    assert a[:3] == [150_000, 75_000, 37_500]
    assert b[:3] == [50_000, 25_000, 12_500]
    assert min(a[-1], b[-1]) >= MIN_SET_POINTS
    # The framing bounds ignore a stray point (0.5-99.5 percentiles).
    stray = layer("d", 10_000)
    stray.xyz[0] = (1000, 1000, 1000)
    bounds = prepare(Scene(("t",), (stray,))).bounds
    assert bounds is not None
    assert bounds.max() < 2


def test_the_caption_says_how_many_points_are_drawn():
    from amrst_gui.views.detail import with_shown

    text = "Target: a.laz, 2,000,000 points\nshowing 200,000 of 2,000,000 points"
    assert "showing 50,000 of 2,000,000 points" in with_shown(text, 50_000)
    small = "x\nshowing all 5,000 points\nwood 20%"
    assert with_shown(small, 5_000) == small
    assert "showing 2,500 of 5,000 points\nwood" in with_shown(small, 2_500)


CANCEL_POINTS = 1_000_000


@pytest.fixture(scope="module")
def cancel_pair(tmp_path_factory):
    return write_dense_pair(tmp_path_factory.mktemp("cancel"), *(CANCEL_POINTS,) * 2)


def _cancel_when(qtbot, s, step: str, trigger, when) -> float:
    """Start ``step``, call Cancel from the progress signal once ``when(message)``
    holds, and return the seconds from Cancel until the app is idle."""
    marks: dict[str, float] = {}

    def on_progress(_fraction: float, message: str) -> None:
        if "cancel" not in marks and s.running_step == step and when(message):
            marks["cancel"] = time.perf_counter()
            s.cancel()

    s.progressed.connect(on_progress)
    try:
        with qtbot.waitSignal(s.cancelled, timeout=300_000):
            trigger()
        qtbot.waitUntil(lambda: not s.busy, timeout=300_000)
    finally:
        s.progressed.disconnect(on_progress)
    assert "cancel" in marks, f"{step} never reported the progress to cancel at"
    return time.perf_counter() - marks["cancel"]


@pytest.mark.slow
def test_every_long_step_stops_within_a_second_of_cancel_and_keeps_nothing(
    make_main_window, qtbot, finish, cancel_pair
):
    """Before issue 15 Accept coarse could not be cancelled (15 s more at 2M
    points) and a cancelled Fine ran on for 21 s and kept its result."""
    win = make_main_window()
    s, a = win.session, win.actions
    with qtbot.waitSignals([s.scan_loaded] * 2, timeout=120_000):
        win.open_pair(*cancel_pair)
    qtbot.waitUntil(lambda: not s.busy, timeout=60_000)
    latency = {}

    latency["separate"] = _cancel_when(
        qtbot, s, "separate", a.separate.trigger, lambda m: True
    )
    assert s.analysis("target") is None
    assert not s.is_done("separate")

    finish(s, a.separate.trigger, "separation_finished", timeout=300_000)
    finish(s, a.skeleton.trigger, "skeletons_finished", timeout=300_000)
    analyses = s.analysis("target")
    latency["match"] = _cancel_when(qtbot, s, "match", a.match.trigger, lambda m: True)
    assert not s.matches
    finish(s, a.match.trigger, "matches_changed", timeout=300_000)
    assert s.coarse is not None, s.coarse_message

    # Accept coarse and Fine at their tree measurements, where they did not stop.
    latency["coarse"] = _cancel_when(
        qtbot, s, "coarse", s.accept_coarse, lambda m: "Measuring the tree" in m
    )
    assert s.accepted_coarse is None
    assert not s.is_done("coarse")
    finish(s, s.accept_coarse, "coarse_accepted", timeout=300_000)
    accepted = s.accepted_coarse
    latency["fine"] = _cancel_when(
        qtbot, s, "fine", lambda: s.run_step("fine"), lambda m: "Measuring" in m
    )
    assert s.fine is None
    assert not s.is_done("fine")
    # Earlier results are kept.
    assert s.accepted_coarse is accepted
    assert s.analysis("target") is analyses
    slow = {k: round(v, 2) for k, v in latency.items() if v > 1.0}
    assert not slow, f"Cancel took over 1 s: {slow}"
