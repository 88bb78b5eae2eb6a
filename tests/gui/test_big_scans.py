"""The app at real scale: big scans load and show a level of detail, the views
draw fewer points while the camera moves, and every step stops soon after Cancel
keeping nothing of its own result. The window's stalls and frame rate are
figures of the app benchmark (``python -m amrst_gui.app_bench``), not tests.

The clouds are generated here (jittered copies of the bundled sample, seeded) and
written to a temporary folder: nothing big is shipped.
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))

from dense_clouds import write_dense_pair

BIG = 2_000_000


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
    win = make_main_window()
    win.open_pair(*big_pair)
    qtbot.waitUntil(lambda: _all_drawn(win), timeout=120_000)
    return win


@pytest.mark.slow
def test_a_big_scan_loads_shows_a_level_of_detail_and_is_described(
    make_main_window, qtbot, big_pair
):
    win = _load_big(make_main_window, qtbot, big_pair)
    boxes = win.scans_panel.boxes.values()
    qtbot.waitUntil(
        lambda: all("median_spacing_m" in b.toolTip() for b in boxes), timeout=60_000
    )
    view = win.scans_area.views()[0]
    shown = view.drawn_points()
    assert 0 < shown <= 200_000
    assert f"showing {shown:,} of {BIG:,} points" in view.caption()


@pytest.mark.slow
def test_the_views_draw_fewer_points_while_the_camera_moves(
    make_main_window, qtbot, big_pair
):
    from amrst_gui.views.scene import MOVING_POINTS

    win = _load_big(make_main_window, qtbot, big_pair)
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
    a = [len(xyz) for xyz, _rgb in out.sets["a"]]
    b = [len(xyz) for xyz, _rgb in out.sets["b"]]
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


def _cancel_when(qtbot, s, step: str, trigger, when) -> None:
    """Start ``step`` and call Cancel from the progress signal once ``when(message)``
    holds; return when the app is idle."""
    marks: dict[str, bool] = {}

    def on_progress(_fraction: float, message: str) -> None:
        if "cancel" not in marks and s.running_step == step and when(message):
            marks["cancel"] = True
            s.cancel()

    s.progressed.connect(on_progress)
    try:
        with qtbot.waitSignal(s.cancelled, timeout=300_000):
            trigger()
        qtbot.waitUntil(lambda: not s.busy, timeout=300_000)
    finally:
        s.progressed.disconnect(on_progress)
    assert "cancel" in marks, f"{step} never reported the progress to cancel at"


@pytest.mark.slow
def test_every_long_step_stops_on_cancel_and_keeps_nothing(
    make_main_window, qtbot, finish, cancel_pair
):
    """Accept coarse and Fine are cancelled while they measure the tree, where
    they have no check point of their own: the engine process is killed."""
    win = make_main_window()
    s, a = win.session, win.actions
    with qtbot.waitSignals([s.scan_loaded] * 2, timeout=120_000):
        win.open_pair(*cancel_pair)
    qtbot.waitUntil(lambda: not s.busy, timeout=60_000)
    _cancel_when(qtbot, s, "separate", a.separate.trigger, lambda m: True)
    assert s.analysis("target") is None
    assert not s.is_done("separate")

    finish(s, a.separate.trigger, "separation_finished", timeout=300_000)
    finish(s, a.skeleton.trigger, "skeletons_finished", timeout=300_000)
    analyses = s.analysis("target")
    _cancel_when(qtbot, s, "match", a.match.trigger, lambda m: True)
    assert not s.matches
    finish(s, a.match.trigger, "matches_changed", timeout=300_000)
    assert s.coarse is not None, s.coarse_message

    # Accept coarse and Fine at their tree measurements, where they did not stop.
    _cancel_when(
        qtbot, s, "coarse", s.accept_coarse, lambda m: "Measuring the tree" in m
    )
    assert s.accepted_coarse is None
    assert not s.is_done("coarse")
    finish(s, s.accept_coarse, "coarse_accepted", timeout=300_000)
    accepted = s.accepted_coarse
    _cancel_when(
        qtbot, s, "fine", lambda: s.run_step("fine"), lambda m: "Measuring" in m
    )
    assert s.fine is None
    assert not s.is_done("fine")
    # Earlier results are kept.
    assert s.accepted_coarse is accepted
    assert s.analysis("target") is analyses
