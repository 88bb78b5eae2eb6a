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
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(Path(__file__).resolve().parent))
from app_speed_child import STEPS  # noqa: E402  (the child's step order)

BEFORE = "eb57aef"  # main before issue 15's app work
CHILD = Path(__file__).resolve().with_name("app_speed_child.py")
_CHILD_KEYS = (
    "phase",
    "frames",
    "trace",
    "target",
    "source",
    "cancel_target",
    "cancel_source",
    "runall_target",
    "runall_source",
)


# -------------------------------------------------------------------- parent
def _checkout(ref: str, folder: Path) -> Path:
    tar = subprocess.run(
        ["git", "-C", str(ROOT), "archive", ref], check=True, capture_output=True
    ).stdout
    subprocess.run(["tar", "-x", "-C", str(folder)], input=tar, check=True)
    return folder


def _run_child(code: Path, args) -> dict:
    env = {**os.environ, "PYTHONPATH": str(code), "QT_API": "pyside6"}
    env.setdefault("LIBGL_ALWAYS_SOFTWARE", "1")
    job = {
        key: str(value) if isinstance(value, Path) else value
        for key, value in vars(args).items()
        if key in _CHILD_KEYS
    }
    cmd = [sys.executable, str(CHILD), json.dumps(job)]
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
        row("Run all: stalls over 100 ms", lambda d: d["runall_stalls_over_100ms"], "")
        row("idle app, 3 s: longest GUI stall", lambda d: d["idle_max_stall_s"])
        row("peak memory: the app (MB)", lambda d: d["peak_mb"]["app"], "")
        row(
            "peak memory: its engine process (MB)", lambda d: d["peak_mb"]["engine"], ""
        )
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
        row(
            f"{step}: stalls over 100 ms",
            lambda d, s=step: d["cancel"][s]["stalls_over_100ms"],
            "",
        )
        row(f"{step}: whole step", lambda d, s=step: d["cancel"][s]["full_s"])
    if before and "orbit_fps" in after:
        lines.append(
            f"\norbit speed-up: {after['orbit_fps'] / before['orbit_fps']:.1f}x"
        )
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
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
        args.runall_target, args.runall_source = (
            pair / "target.laz",
            pair / "source.laz",
        )
    before = None
    if not args.no_before:
        with tempfile.TemporaryDirectory(prefix="amrst-before-") as tmp:
            before = _run_child(_checkout(args.before, Path(tmp)), args)
    after = _run_child(ROOT, args)
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
