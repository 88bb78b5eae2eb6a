"""The app benchmark: GUI-thread stalls, orbit frame rate and Cancel latency.

Run it under a display (Xvfb and software OpenGL are fine), from the repository::

    xvfb-run -a -s "-screen 0 1920x1080x24" python -m amrst_gui.app_bench

It writes a pair of ``--points`` points per scan with ``amrst.bench.scale`` (kept
in ``--data`` for the next run), opens it in the window as a user would and
measures, with a 10 ms timer on the GUI thread (its longest silence is the longest
time the window could not answer):

- load: the time until both scan views and the overlay show points, and the
  longest stall meanwhile (the descriptions and every view included);
- orbit: frames per second while the mouse drags the target view;
- run all: click to idle, each step's seconds, the longest stall and how many
  stalls exceeded 100 ms;
- cancel: each step started again and cancelled (Accept coarse and Fine once they
  measure the tree, the others 1 s in): seconds until the app is idle, and whether
  the step kept anything.

It prints a table and, last, the same figures as one JSON line.
"""

from __future__ import annotations

import argparse
import faulthandler
import json
import os
import sys
import tempfile
import time
from pathlib import Path

STEPS = ("separate", "skeleton", "match", "coarse", "fine")


class Watchdog:
    """A 10 ms QTimer on the GUI thread; ``max_gap_s`` is its longest silence.

    With ``trace_s``, every thread's stack goes to stderr whenever the GUI thread
    has not ticked for that long (``faulthandler``), to find what stalls it.
    """

    def __init__(self, trace_s: float | None = None) -> None:
        from PySide6.QtCore import QTimer

        self.trace_s = trace_s
        self.timer = QTimer()
        self.timer.setInterval(10)
        self.timer.timeout.connect(self._tick)
        self.reset()
        self.timer.start()

    def reset(self) -> None:
        self.last = time.perf_counter()
        self.max_gap_s = 0.0
        self.over_100ms = 0

    def _tick(self) -> None:
        now = time.perf_counter()
        self.max_gap_s = max(self.max_gap_s, now - self.last)
        self.over_100ms += now - self.last > 0.1
        self.last = now
        if self.trace_s:
            faulthandler.cancel_dump_traceback_later()
            faulthandler.dump_traceback_later(self.trace_s)


def _wait(app, cond, timeout_s: float) -> bool:
    end = time.perf_counter() + timeout_s
    while not cond():
        if time.perf_counter() > end:
            return False
        app.processEvents()
        time.sleep(0.002)
    return True


def _settle(app, seconds: float) -> None:
    _wait(app, lambda: False, seconds)


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
    win.resize(1600, 1000)
    win.show()
    _wait(app, win.isVisible, 10)
    _settle(app, 1.0)
    return app, win


def load(app, win, pair: tuple[Path, Path], dog: Watchdog) -> dict:
    """Open the pair; seconds until every view shows points, the longest stall."""
    dog.reset()
    start = time.perf_counter()
    win.open_pair(*pair)
    ok = _wait(app, lambda: _points_shown(win) and not win.session.busy, 600)
    visible = time.perf_counter() - start
    boxes = win.scans_panel.boxes.values()
    _wait(app, lambda: all("median_spacing_m" in b.toolTip() for b in boxes), 120)
    _settle(app, 2.0)
    return {
        "load_visible_s": visible if ok else None,
        "load_described_s": time.perf_counter() - start - 2.0,
        "load_max_stall_s": dog.max_gap_s,
    }


def orbit(app, win, frames: int = 30) -> dict:
    """Drag across the target view; frames per second while it moves."""
    view = win.scans_area.panes["target"].view
    iren = view.plotter.iren.interactor
    x0, y = view.plotter.width() // 2 - frames, view.plotter.height() // 2
    iren.SetEventInformation(x0, y, 0, 0)
    iren.LeftButtonPressEvent()
    times = []
    for i in range(1, frames + 1):
        t = time.perf_counter()
        iren.SetEventInformation(x0 + 2 * i, y, 0, 0)
        iren.MouseMoveEvent()  # the interactor style renders the frame ...
        app.processEvents()  # ... and Qt shows it, as in a real drag
        times.append(time.perf_counter() - t)
    iren.LeftButtonReleaseEvent()
    _settle(app, 1.0)
    times = times[2:]  # the first frames switch to the moving level of detail
    return {"orbit_fps": len(times) / sum(times)}


def run_all(app, win, dog: Watchdog) -> dict:
    """Run all on the open pair; click to idle, each step, the stalls."""
    s = win.session
    print("--- run all", file=sys.stderr, flush=True)
    dog.reset()
    start = time.perf_counter()
    s.run_all()
    _wait(app, lambda: not s.busy, 1800)
    whole = time.perf_counter() - start
    out = {
        "runall_s": whole,
        "runall_max_stall_s": dog.max_gap_s,
        "runall_stalls_over_100ms": dog.over_100ms,
        "runall_reached_fine": s.fine is not None,
    }
    _settle(app, 2.0)
    return out


def _result_of(s, step: str):
    return {
        "separate": lambda: s.analysis("target"),
        "skeleton": lambda: s.analysis("target"),
        "match": lambda: s.matches,
        "coarse": lambda: s.accepted_coarse,
        "fine": lambda: s.fine,
    }[step]()


def cancel_each(app, win, dog: Watchdog) -> dict:
    """Each step started and cancelled; seconds from Cancel to idle."""
    s = win.session
    messages: list[str] = []
    s.progressed.connect(lambda _f, m: messages.append(m))
    out: dict = {}
    for step in STEPS:
        before = _result_of(s, step)
        messages.clear()
        dog.reset()
        start = time.perf_counter()
        s.run_step(step)
        late = step in ("coarse", "fine")  # where they once did not stop

        def due(late=late, t0=start) -> bool:
            if late:
                return any("Measuring the tree" in m for m in messages)
            return time.perf_counter() - t0 > 1.0

        _wait(app, lambda: not s.busy or due(), 300)
        if not s.busy:
            out[step] = {"cancel_s": None, "note": "finished before the cancel"}
        else:
            t = time.perf_counter()
            s.cancel()
            _wait(app, lambda: not s.busy, 300)
            out[step] = {
                "cancel_s": time.perf_counter() - t,
                "kept_result": _result_of(s, step) is not before,
            }
        out[step]["max_stall_s"] = dog.max_gap_s
        s.run_step(step)  # the next step needs this one
        _wait(app, lambda: not s.busy, 900)
    return out


def make_pair(folder: Path, points: int) -> tuple[Path, Path]:
    """The scale pair of ``points`` per scan in ``folder`` (written when missing)."""
    from amrst.bench.scale import make_scale_pair
    from amrst.resources import resource_path

    pair = folder / f"pair_{points}"
    if not (pair / "source.laz").is_file():
        make_scale_pair(resource_path("sample"), pair, points)
    return pair / "target.laz", pair / "source.laz"


def report(out: dict) -> str:
    """The figures as a two-column markdown table."""

    def fmt(v) -> str:
        if isinstance(v, float):
            return f"{v:.2f}"
        return "-" if v is None else str(v)

    rows = [(k, v) for k, v in out.items() if k != "cancel"]
    for step, d in out.get("cancel", {}).items():
        rows += [(f"cancel {step}: {k}", v) for k, v in d.items()]
    return "\n".join(
        ["| figure | value |", "|---|---|"] + [f"| {k} | {fmt(v)} |" for k, v in rows]
    )


def main(argv: list[str] | None = None) -> int:
    """Entry point of ``python -m amrst_gui.app_bench``."""
    p = argparse.ArgumentParser(
        prog="python -m amrst_gui.app_bench", description=__doc__.split("\n")[0]
    )
    p.add_argument("--points", type=int, default=2_000_000, help="points per scan")
    p.add_argument(
        "--data",
        type=Path,
        default=Path(tempfile.gettempdir()) / "amrst-app-bench",
        help="where the generated pair is kept",
    )
    p.add_argument("--no-cancel", action="store_true", help="skip the cancel phase")
    p.add_argument(
        "--trace",
        type=float,
        metavar="S",
        help="print every thread's stack when the GUI thread stalls S seconds",
    )
    args = p.parse_args(argv)
    os.environ.setdefault("QT_API", "pyside6")
    pair = make_pair(args.data, args.points)
    app, win = _window()
    dog = Watchdog(args.trace)
    out = {"points_per_scan": args.points}
    out.update(load(app, win, pair, dog))
    out.update(orbit(app, win))
    out.update(run_all(app, win, dog))
    if not args.no_cancel:
        out["cancel"] = cancel_each(app, win, dog)
    faulthandler.cancel_dump_traceback_later()
    win.close()
    print(report(out))
    print(json.dumps(out))
    return 0


if __name__ == "__main__":
    sys.exit(main())
