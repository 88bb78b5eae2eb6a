"""The app at real scale: GUI-thread stalls, orbit frame rate, cancel latency.

Run under Xvfb (software OpenGL), from the repository root::

    PYTHONPATH=$PWD xvfb-run -a -s "-screen 0 1920x1080x24" \\
        /work/main/.venv/bin/python docs/bench/app_speed.py

It measures this checkout ("after") and, in the same run, the commit given by
``--before`` (default: the last commit before issue 15's app work), checked out
with ``git archive`` into a temporary folder ("before"). Each version runs in its
own process, one after the other, on the same generated clouds (jittered copies of
the bundled sample, seeded, written to ``--data``):

- load: open a 10M-point target and a 2M-point source as a user would
  (``MainWindow.open_pair``); the time until both scan views and the overlay
  show points, and the longest gap of a 10 ms QTimer on the GUI thread
  (a watchdog: the longest time the window could not respond);
- orbit: drag the mouse across the target view (left button, as a user orbits)
  and time the frames drawn while it moves; frames per second;
- runall: open ``--runall-target`` and ``--runall-source`` (default: the 2M + 2M
  pair of ``amrst bench-scale``, written to ``--data`` when missing), Cancel the
  load once the first chunk of points is read (time to idle, to the reading's
  end), open the pair again, then Run all
  as a user would; the seconds of each step as the session timed it, the whole
  run from the click to idle, and the longest GUI stall meanwhile;
- cancel: on a 2M + 2M pair, start each step, cancel it 1 s in (Accept coarse and
  Fine: as soon as they report "Measuring the tree", where they did not stop),
  and time until the app is idle again; whether the cancelled step's result was
  kept.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
BEFORE = "eb57aef"  # main before issue 15's app work
STEPS = ("separate", "skeleton", "match", "coarse", "fine")


# --------------------------------------------------------------------- child
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

    def _tick(self) -> None:
        now = time.perf_counter()
        self.max_gap_s = max(self.max_gap_s, now - self.last)
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
        "runall_fine": None if s.fine is None else s.fine.method,
    }


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


# -------------------------------------------------------------------- parent
def _checkout(ref: str, folder: Path) -> Path:
    tar = subprocess.run(
        ["git", "-C", str(ROOT), "archive", ref], check=True, capture_output=True
    ).stdout
    subprocess.run(["tar", "-x", "-C", str(folder)], input=tar, check=True)
    return folder


def _run_child(code: Path, args, phase: str) -> dict:
    env = {**os.environ, "PYTHONPATH": str(code), "QT_API": "pyside6"}
    env.setdefault("LIBGL_ALWAYS_SOFTWARE", "1")
    cmd = [
        sys.executable,
        str(Path(__file__).resolve()),
        "--child",
        "--phase",
        phase,
        "--frames",
        str(args.frames),
        *("--target", str(args.target), "--source", str(args.source)),
        *("--cancel-target", str(args.cancel_target)),
        *("--cancel-source", str(args.cancel_source)),
        *("--runall-target", str(args.runall_target)),
        *("--runall-source", str(args.runall_source)),
        *(("--trace", str(args.trace)) if args.trace else ()),
    ]
    proc = subprocess.run(cmd, env=env, capture_output=True, text=True, check=False)
    if args.trace:
        sys.stderr.write(proc.stderr)
    for line in proc.stdout.splitlines():
        if line.startswith("RESULT "):
            return json.loads(line[7:])
    sys.stderr.write(proc.stderr[-3000:])
    raise SystemExit(f"the {code} run failed (exit {proc.returncode})")


def _fmt(v, unit: str = "s") -> str:
    if v is None:
        return "-"
    return f"{v:.2f} {unit}" if unit else f"{v:.1f}"


def report(before: dict | None, after: dict) -> str:
    cols = [("before", before), ("after", after)] if before else [("after", after)]
    lines = ["| | " + " | ".join(c for c, _ in cols) + " |"]
    lines.append("|---" * (len(cols) + 1) + "|")

    def row(label, get, unit="s"):
        vals = []
        for _, d in cols:
            try:
                vals.append(_fmt(get(d), unit))
            except (KeyError, TypeError):
                vals.append("-")
        lines.append(f"| {label} | " + " | ".join(vals) + " |")

    if "points_visible_s" in after:
        row("points visible after load", lambda d: d["points_visible_s"])
        row("longest GUI stall while loading", lambda d: d["load_max_stall_s"])
        row("orbit frames per second", lambda d: d["orbit_fps"], "")
        row("full-detail frame after the orbit", lambda d: d["rest_frame_s"])
    if "runall_s" in after:
        row("Cancel while loading: idle after", lambda d: d["load_cancel_s"])
        row(
            "Cancel while loading: reading stopped after",
            lambda d: d["load_worker_stopped_s"],
        )
        row("Load that could not be cancelled: ran for", lambda d: d["load_full_s"])
        row("Run all: click to idle", lambda d: d["runall_s"])
        for step in STEPS:
            row(f"Run all: {step}", lambda d, s=step: d["runall_steps_s"][s])
        row("Run all: longest GUI stall", lambda d: d["runall_max_stall_s"])
    for step in STEPS if "cancel" in after else ():
        row(f"{step}: idle after Cancel", lambda d, s=step: d["cancel"][s]["cancel_s"])
        row(
            f"{step}: computation stopped after",
            lambda d, s=step: d["cancel"][s]["worker_stopped_s"],
        )
        lines.append(
            f"| {step}: result kept after cancel | "
            + " | ".join(
                str(d["cancel"][step].get("kept_result", "-")) for _, d in cols
            )
            + " |"
        )
        row(
            f"{step}: longest GUI stall",
            lambda d, s=step: d["cancel"][s]["max_stall_s"],
        )
        row(f"{step}: whole step", lambda d, s=step: d["cancel"][s]["full_s"])
    if before and "orbit_fps" in after:
        lines.append(
            f"\norbit speed-up: {after['orbit_fps'] / before['orbit_fps']:.1f}x"
        )
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--child", action="store_true", help=argparse.SUPPRESS)
    p.add_argument(
        "--phase", choices=("load", "runall", "cancel", "all"), default="all"
    )
    p.add_argument("--before", default=BEFORE, help="git ref to compare with")
    p.add_argument("--no-before", action="store_true", help="measure this tree only")
    p.add_argument("--points", type=int, default=10_000_000)
    p.add_argument("--source-points", type=int, default=2_000_000)
    p.add_argument("--cancel-points", type=int, default=2_000_000)
    p.add_argument("--frames", type=int, default=30)
    p.add_argument(
        "--trace",
        type=float,
        nargs="?",
        const=0.3,
        help="print what the GUI thread runs when it stalls this long (s)",
    )
    p.add_argument(
        "--data", type=Path, default=Path(tempfile.gettempdir()) / "amrst-app-speed"
    )
    p.add_argument("--target", type=Path)
    p.add_argument("--source", type=Path)
    p.add_argument("--cancel-target", type=Path)
    p.add_argument("--cancel-source", type=Path)
    p.add_argument("--runall-target", type=Path)
    p.add_argument("--runall-source", type=Path)
    args = p.parse_args(argv)
    if args.child:
        child(args)
        return 0
    sys.path.insert(0, str(ROOT / "tests" / "benchmarks"))
    sys.path.insert(0, str(ROOT))
    from dense_clouds import write_dense_pair

    args.target, args.source = write_dense_pair(
        args.data, args.points, args.source_points
    )
    args.cancel_target, args.cancel_source = write_dense_pair(
        args.data, args.cancel_points, args.cancel_points
    )
    if args.runall_target is None or args.runall_source is None:
        from amrst.bench.scale import make_scale_pair

        pair = args.data / "pair_2000000"
        if not (pair / "source.laz").is_file():
            make_scale_pair(ROOT / "resources" / "sample", pair, 2_000_000)
        args.runall_target, args.runall_source = pair / "target.laz", pair / "source.laz"
    before = None
    if not args.no_before:
        with tempfile.TemporaryDirectory(prefix="amrst-before-") as tmp:
            before = _run_child(_checkout(args.before, Path(tmp)), args, args.phase)
    after = _run_child(ROOT, args, args.phase)
    print(
        f"{args.points:,}-point target, {args.source_points:,}-point source; "
        f"cancel on {args.cancel_points:,} + {args.cancel_points:,}; "
        f"before = {args.before if before else '-'}"
    )
    print(report(before, after))
    print(json.dumps({"before": before, "after": after}))
    return 0


if __name__ == "__main__":
    sys.exit(main())
