"""VTK objects are never made in a worker while the GUI thread drops a view's.

A CI run and a fresh-clone run hung for good in a test teardown: closing a view ran VTK's garbage
collector, which called back into Python and let the GIL go to a scene worker
making a ``pyvista.PolyData``; that worker then waited for the collector's mutex
while holding the GIL (``amrst_gui/views/vtk_lock.py``). These tests check the
protocol that keeps the two apart.
"""

from __future__ import annotations

import threading
import time

import numpy as np
import pytest


def _scene(n: int, key: str):
    from amrst_gui.views.layers import PointsLayer, Scene

    rng = np.random.default_rng(len(key))
    xyz = rng.random((n, 3)).astype(np.float32)
    return Scene(
        ("f",), (PointsLayer("points", (key,), xyz, np.zeros((n, 3), np.uint8)),)
    )


def test_a_worker_makes_no_vtk_object_while_the_gui_thread_holds_the_lock():
    from amrst_gui.views.scene_jobs import prepare
    from amrst_gui.views.vtk_lock import VTK_LOCK

    out: list = []
    worker = threading.Thread(target=lambda: out.append(prepare(_scene(5_000, "a"))))
    with VTK_LOCK:
        worker.start()
        worker.join(0.3)
        assert worker.is_alive()  # waiting for the lock, not making objects
        assert not out
    worker.join(20)
    assert not worker.is_alive()
    assert len(out) == 1
    assert out[0].sets["points"]


def test_closing_and_redrawing_a_view_wait_for_the_object_being_made(qtbot):
    from amrst_gui.views.scan_view import ScanView
    from amrst_gui.views.scene_jobs import prepare
    from amrst_gui.views.vtk_lock import VTK_LOCK

    view = ScanView()
    qtbot.addWidget(view)
    first = _scene(5_000, "first")
    view.update_scene(first, prepare(first))
    released = {}
    holding = threading.Event()

    def worker_making_an_object() -> None:
        with VTK_LOCK:
            holding.set()
            time.sleep(0.3)
            released["at"] = time.perf_counter()

    for act in (
        lambda: view.update_scene(_scene(5_000, "second")),  # replaces the actors
        view.close_view,
    ):
        holding.clear()
        worker = threading.Thread(target=worker_making_an_object)
        worker.start()
        assert holding.wait(10)
        act()
        done = time.perf_counter()
        worker.join(10)
        assert done >= released["at"]
    assert view.closed


class _Probe:
    """Records, when it dies, in which thread and whether that thread held the lock."""

    def __init__(self, seen: list) -> None:
        self.seen = seen

    def __del__(self) -> None:
        from amrst_gui.views.vtk_lock import VTK_LOCK

        self.seen.append(
            (
                threading.current_thread() is threading.main_thread(),
                VTK_LOCK._is_owned(),
            )
        )


@pytest.mark.parametrize("stale", ["discarded", "ignored"])
def test_a_result_nobody_takes_dies_on_the_gui_thread_under_the_lock(qtbot, stale):
    """A stale scene (a newer one replaced it, its job was discarded) is dropped by
    the GUI thread under the lock, never by the worker or by Qt's signal cleanup."""
    from amrst_gui import workers

    seen: list = []
    started = threading.Event()

    def work(reporter) -> _Probe:
        started.set()
        time.sleep(0.05)
        return _Probe(seen)

    got: list = []
    job = workers.run_stage(work, name="probe", on_result=lambda out: None)
    if stale == "discarded":
        assert started.wait(10)
        job.discard()
    else:  # delivered to a slot that keeps nothing
        job.returned.connect(lambda out: got.append(type(out).__name__))
    qtbot.waitUntil(lambda: bool(seen), timeout=10_000)
    assert seen == [(True, True)]
    assert got == ([] if stale == "discarded" else ["_Probe"])
