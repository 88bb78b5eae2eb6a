"""The measuring half of ``app_speed.py``: runs in its own process, prints RESULT.

``app_speed.py`` starts this script once per code version (with PYTHONPATH set to
that version's checkout) and passes its settings as one JSON argument; see its
docstring for what each phase measures.
"""

from __future__ import annotations

import json
import os
import sys
import tempfile
import time
from pathlib import Path
from types import SimpleNamespace

STEPS = ("separate", "skeleton", "match", "coarse", "fine")


class Watchdog:
    """A 10 ms QTimer on the GUI thread; ``max_gap_s`` is the longest time between
    two ticks (a stall: the window could not repaint or take a click)."""

    def __init__(self) -> None:
        from PySide6.QtCore import QTimer

        self.timer = QTimer()
        self.timer.setInterval(10)
        self.timer.timeout.connect(self._tick)
        self.reset()
        self.timer.start()

    def trace(self, after_s: float = 0.3) -> None:
        """Debugging aid (``--trace``): print the GUI thread's stack to stderr
        whenever it has not ticked for ``after_s``, to find what stalls it."""
        import threading
        import traceback

        main = threading.main_thread().ident

        def watch() -> None:
            while True:
                time.sleep(after_s / 2)
                if time.perf_counter() - self.last > after_s:
                    # Every thread: a worker in a long C call that holds the
                    # GIL stalls the GUI thread too.
                    stacks = [
                        f"-- thread {ident}{' (GUI)' if ident == main else ''}\n"
                        + "".join(traceback.format_stack(frame)[-6:])
                        for ident, frame in sys._current_frames().items()
                        if ident != threading.get_ident()
                    ]
                    sys.stderr.write(
                        f"STALL {time.perf_counter() - self.last:.2f}s\n"
                        + "".join(stacks)
                    )

        threading.Thread(target=watch, daemon=True).start()

    def reset(self) -> None:
        self.last = time.perf_counter()
        self.max_gap_s = 0.0
        self.over_100ms = 0  # how many stalls were longer than the 100 ms target

    def _tick(self) -> None:
        now = time.perf_counter()
        self.max_gap_s = max(self.max_gap_s, now - self.last)
        self.over_100ms += now - self.last > 0.1
        self.last = now


def _wait(app, cond, timeout_s: float) -> bool:
    end = time.perf_counter() + timeout_s
    while not cond():
        if time.perf_counter() > end:
            return False
        app.processEvents()
        time.sleep(0.002)
    return True


def _points_shown(win) -> bool:
    views = [p.view for p in win.scans_area.panes.values()]
    return all("points" in v.actor_names() for v in views) and (
        "target_points" in win.registration.view.actor_names()
    )


def _window():
    from PySide6.QtCore import QSettings

    from amrst_gui.app import create_app

    QSettings.setPath(
        QSettings.Format.IniFormat,
        QSettings.Scope.UserScope,
        tempfile.mkdtemp(prefix="amrst-bench-settings-"),
    )
    app = create_app(sys.argv[:1])
    from amrst_gui.main_window import MainWindow

    win = MainWindow()
    win.session.discard_guard = None
    win.show()
    _wait(app, win.isVisible, 10)
    for _ in range(20):
        app.processEvents()
    return app, win


def _load(app, win, target: Path, source: Path, dog: Watchdog) -> dict:
    dog.reset()
    start = time.perf_counter()
    win.open_pair(target, source)
    ok = _wait(app, lambda: _points_shown(win) and not win.session.busy, 600)
    visible = time.perf_counter() - start
    # Whatever else the load queued (descriptions, the other views) finishes too.
    _wait(app, lambda: False, 3.0)
    return {
        "points_visible_s": visible if ok else None,
        "load_max_stall_s": dog.max_gap_s,
    }


def _orbit(app, win, frames: int) -> dict:
    view = win.scans_area.panes["target"].view
    iren = view.plotter.iren.interactor
    w, h = view.plotter.width(), view.plotter.height()
    x0, y = w // 2 - frames, h // 2
    for _ in range(5):
        app.processEvents()
    iren.SetEventInformation(x0, y, 0, 0)
    iren.LeftButtonPressEvent()
    times = []
    for i in range(1, frames + 1):
        t = time.perf_counter()
        iren.SetEventInformation(x0 + 2 * i, y, 0, 0)
        iren.MouseMoveEvent()  # the interactor style renders the frame ...
        app.processEvents()  # ... and Qt shows it (paintGL), as in a real drag
        times.append(time.perf_counter() - t)
    t = time.perf_counter()
    iren.LeftButtonReleaseEvent()
    app.processEvents()
    rest = time.perf_counter() - t
    times = sorted(times[2:])  # the first frames may set up the moving display
    mean = sum(times) / len(times)
    return {"orbit_fps": 1.0 / mean, "orbit_frames": len(times), "rest_frame_s": rest}


def _cancel(app, win, target: Path, source: Path, dog: Watchdog) -> dict:
    s = win.session
    win.open_pair(target, source)
    _wait(app, lambda: _points_shown(win) and not s.busy, 600)
    _wait(app, lambda: False, 3.0)  # the descriptions and the other views
    out: dict = {}
    messages: list[str] = []
    s.progressed.connect(lambda _f, m: messages.append(m))
    for step in STEPS:
        before = _result_of(s, step)
        messages.clear()
        dog.reset()
        start = time.perf_counter()
        s.run_step(step)
        long_part = step in ("coarse", "fine")
        _wait(
            app,
            lambda lp=long_part, t0=start: (
                not s.busy
                or (any("Measuring the tree" in m for m in messages) if lp else False)
                or (time.perf_counter() - t0 > (60 if lp else 1.0))
            ),
            120,
        )
        if not s.busy:
            out[step] = {"cancel_s": None, "note": "finished before the cancel"}
        else:
            job = getattr(s, "_job", None)
            t = time.perf_counter()
            s.cancel()
            _wait(app, lambda: not s.busy, 300)
            idle = time.perf_counter() - t
            # The computation itself: the worker thread returns (at its next
            # cancel check point, or at its end where there is none).
            done = getattr(job, "worker_done", None)
            if done is not None:
                _wait(app, done.is_set, 300)
            out[step] = {
                "cancel_s": idle,
                "worker_stopped_s": time.perf_counter() - t,
                "kept_result": _result_of(s, step) is not before,
                "into_step_s": t - start,
            }
        out[step]["max_stall_s"] = dog.max_gap_s
        out[step]["stalls_over_100ms"] = dog.over_100ms
        # The next step needs this one: run it to the end.
        t = time.perf_counter()
        s.run_step(step)
        _wait(app, lambda: not s.busy, 900)
        out[step]["full_s"] = time.perf_counter() - t
    return out


def _cancel_load(app, win, target: Path, source: Path) -> dict:
    """Open the pair and Cancel once the first chunk of points was read; seconds
    until the app is idle and until the reading stopped (LAS/LAZ only)."""
    s = win.session
    marks: dict = {}

    def on_progress(_f: float, message: str) -> None:
        if "cancel" not in marks and "points read" in message:
            marks["job"] = getattr(s, "_job", None)
            marks["cancel"] = time.perf_counter()
            s.cancel()

    s.progressed.connect(on_progress)
    start = time.perf_counter()
    win.open_pair(target, source)
    _wait(app, lambda: "cancel" in marks or not s.busy, 600)
    s.progressed.disconnect(on_progress)
    if "cancel" not in marks:  # no chunked reading (a version before it): the
        # load ran to its end (and Cancel did not stop it then either)
        return {"load_cancel_s": None, "load_full_s": time.perf_counter() - start}
    _wait(app, lambda: not s.busy, 600)
    idle = time.perf_counter() - marks["cancel"]
    done = getattr(marks["job"], "worker_done", None)
    if done is not None:
        _wait(app, done.is_set, 600)
    return {
        "load_cancel_s": idle,
        "load_worker_stopped_s": time.perf_counter() - marks["cancel"],
        "load_kept_scans": s.cloud("target") is not None,
    }


def _runall(app, win, target: Path, source: Path, dog: Watchdog) -> dict:
    s = win.session
    out = _cancel_load(app, win, target, source)
    win.open_pair(target, source)
    _wait(app, lambda: _points_shown(win) and not s.busy, 600)
    _wait(app, lambda: False, 3.0)  # the descriptions and the other views
    # The floor: the longest stall with the app idle, as busy as the machine is.
    dog.reset()
    _wait(app, lambda: False, 3.0)
    idle = dog.max_gap_s
    dog.reset()
    start = time.perf_counter()
    s.run_all()
    _wait(app, lambda: not s.busy, 1800)
    whole = time.perf_counter() - start
    timings = dict(getattr(s, "_timings", {}))
    return {
        **out,
        "runall_s": whole,
        "runall_steps_s": {k: v for k, v in timings.items() if k != "load"},
        "runall_max_stall_s": dog.max_gap_s,
        "runall_stalls_over_100ms": dog.over_100ms,
        "idle_max_stall_s": idle,
        "runall_fine": None if s.fine is None else s.fine.method,
        "peak_mb": _peak_mb(),
    }


def _peak_mb() -> dict:
    """Peak resident memory (VmHWM) of this process and of the engine process."""

    def hwm(pid) -> float | None:
        try:
            status = Path(f"/proc/{pid}/status").read_text()
        except OSError:
            return None
        kb = next((ln.split()[1] for ln in status.splitlines() if "VmHWM" in ln), None)
        return None if kb is None else int(kb) / 1024

    try:
        from amrst_gui.engine_process import ENGINE
    except ImportError:  # a version before the engine process
        engine = None
    else:
        engine = hwm(ENGINE.pid) if ENGINE.pid else None
    return {"app": hwm("self"), "engine": engine}


def _result_of(s, step: str):
    return {
        "separate": lambda: s.analysis("target"),
        "skeleton": lambda: s.analysis("target"),
        "match": lambda: s.matches,
        "coarse": lambda: s.accepted_coarse,
        "fine": lambda: s.fine,
    }[step]()


def child(args) -> None:
    os.environ.setdefault("QT_API", "pyside6")
    app, win = _window()
    dog = Watchdog()
    if args.trace:
        dog.trace(args.trace)
    out: dict = {}
    if args.phase in ("load", "all"):
        out.update(_load(app, win, args.target, args.source, dog))
        out.update(_orbit(app, win, args.frames))
    if args.phase in ("runall", "all"):
        out.update(_runall(app, win, args.runall_target, args.runall_source, dog))
    if args.phase in ("cancel", "all"):
        out["cancel"] = _cancel(app, win, args.cancel_target, args.cancel_source, dog)
    win.close()
    print("RESULT " + json.dumps(out))


if __name__ == "__main__":
    job = json.loads(sys.argv[1])
    for key in ("target", "source", "cancel_target", "cancel_source"):
        job[key] = Path(job[key])
    for key in ("runall_target", "runall_source"):
        job[key] = Path(job[key])
    child(SimpleNamespace(**job))
