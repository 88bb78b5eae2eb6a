"""Scale benchmark: dense pairs made from a case, timed per stage with peak memory.

Real TLS scans of one tree hold millions of points; the shared cases hold thousands.
:func:`~amrst.bench.densify.densify` makes a dense scan from a sparse one by jittered copies of its points
(seeded Gaussian noise, 3 mm by default, in the scan's own frame, so the case's truth
still holds); :func:`make_scale_pair` writes such a pair as LAZ beside a copy of the
truth. :func:`time_register` runs the whole ``amrst register`` command on a pair in a
child process and reads back its per-stage timings and its peak resident memory;
``kiss_ratio`` times our registration against KISS-Matcher + small_gicp GICP on
the same clouds in one process (``amrst.bench.kiss``). ``amrst bench-scale`` prints
both as tables; on a plot case it times ``amrst plot`` instead
(``amrst.bench.scale_plot``).
"""

from __future__ import annotations

import json
import os
import sys
import tempfile
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING

from amrst.bench.child import run_amrst
from amrst.bench.densify import dense_name, densify
from amrst.bench.markdown import markdown_table
from amrst.errors import InvalidInput
from amrst.simulate.settings import Bounds

if TYPE_CHECKING:
    import argparse
    from collections.abc import Sequence

    from amrst.bench.scale_plot import PlotScaleRow

PathLike = str | os.PathLike[str]
# Stages in the order the pipeline runs them (the table's columns).
STAGES = (
    "read",
    "preprocess",
    "separate",
    "skeleton",
    "keypoints",
    "match",
    "verify",
    "trunk",
    "fine",
    "metrics",
)


def make_scale_pair(
    case_dir: PathLike,
    out_dir: PathLike,
    n_points: int,
    noise_m: float = 0.003,
    seed: int = 0,
) -> Path:
    """Write ``target.laz``, ``source.laz`` (``n_points`` each) and ``truth.json``.

    Parameters
    ----------
    case_dir : path
        A case folder (``target.*``, ``source.*``, ``truth.json``).
    out_dir : path
        Created when missing.
    n_points : int
        Points per scan.
    noise_m : float
    seed : int
        The target uses ``seed``, the source ``seed + 1``.

    Returns
    -------
    Path
        The folder written.
    """
    from amrst import io
    from amrst.files.atomic import make_folder, write_json_atomic
    from amrst.io.cases import read_case

    case = read_case(case_dir)
    out = make_folder(out_dir, "scale case folder")
    for role, cloud, s in (
        ("target", case.target, seed),
        ("source", case.source, seed + 1),
    ):
        io.write(out / f"{role}.laz", densify(cloud, n_points, noise_m, s))
    truth = dict(case.truth)
    truth.update(
        densified_from=str(case_dir),
        densify_points=n_points,
        densify_noise_m=noise_m,
        densify_seed=seed,
    )
    write_json_atomic(out / "truth.json", truth, indent=1)
    return out


@dataclass(frozen=True, slots=True)
class ScaleRow:
    """One whole ``amrst register`` command on one pair."""

    name: str
    n_target: int
    n_source: int
    wall_s: float  # the whole command, interpreter start included
    peak_mb: float  # peak resident memory of the command
    exit_code: int
    timings: dict[str, float] = field(default_factory=dict)  # stage -> s

    @property
    def measured(self) -> bool:
        """Whether the command ran to the end and wrote its timings."""
        return bool(self.timings)


def time_register(
    pair_dir: PathLike, n_points: int | None = None, extra: Sequence[str] = ()
) -> ScaleRow:
    """Run ``amrst register`` on a pair folder in a child process.

    Parameters
    ----------
    pair_dir : path
        Holds ``target.*`` and ``source.*`` (LAZ, LAS, PLY...) and ``truth.json``.
    n_points : int or None
        Points per scan for the table (read from ``truth.json`` when None).
    extra : sequence of str
        More ``amrst register`` arguments.

    Returns
    -------
    ScaleRow
        Peak memory is the child's maximum resident set size (``wait4``).
    """
    from amrst.io.cases import case_scan

    pair = Path(pair_dir)
    files = {role: case_scan(pair, role) for role in ("target", "source")}
    truth = json.loads((pair / "truth.json").read_text())
    n = n_points or int(truth.get("densify_points", 0))
    with tempfile.TemporaryDirectory(prefix="amrst-scale-") as tmp:
        child = run_amrst(
            "register",
            str(files["target"]),
            str(files["source"]),
            "--out",
            tmp,
            "--quiet",
            "--truth",
            str(pair / "truth.json"),
            *extra,
        )
        timings: dict[str, float] = {}
        doc = Path(tmp) / "transform.json"
        if doc.exists():
            timings = {
                k: float(v)
                for k, v in json.loads(doc.read_text()).get("timings_s", {}).items()
            }
    return ScaleRow(
        pair.name,
        n or int(truth.get("n_target", 0)),
        n or int(truth.get("n_source", 0)),
        child.wall_s,
        child.peak_mb,
        child.exit_code,
        timings,
    )


def format_scale_table(rows: Sequence[ScaleRow]) -> str:
    """Format rows as a Markdown table: points, seconds per stage, command, peak memory."""
    head = ["pair", "points/scan", *STAGES, "total", "command", "peak MB", "exit"]
    table = []
    for r in rows:
        cells = [r.name, f"{r.n_target:,}"]
        cells += [f"{r.timings[s]:.2f}" if s in r.timings else "-" for s in STAGES]
        total = r.timings.get("total", float("nan")) + r.timings.get("read", 0.0)
        cells += [
            f"{total:.2f}",
            f"{r.wall_s:.2f}",
            f"{r.peak_mb:.0f}",
            str(r.exit_code),
        ]
        table.append(cells)
    return markdown_table(head, table).rstrip("\n")


def configure_parser(p: argparse.ArgumentParser) -> None:
    """Add the ``amrst bench-scale`` arguments to ``p``."""
    p.add_argument(
        "case_dir",
        metavar="CASE_DIR",
        help="the case folder to densify (target.*, source.*, truth.json); a plot case "
        "times amrst plot",
    )
    p.add_argument(
        "--points",
        type=int,
        nargs="+",
        default=[2_000_000],
        metavar="N",
        help="points per scan of each dense pair or plot (default 2000000)",
    )
    p.add_argument("--noise-m", type=float, default=0.003, help="jitter (m)")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument(
        "--out",
        default="bench_scale",
        metavar="DIR",
        help="dense scans and tables go here (dense scans made before are reused)",
    )
    p.add_argument(
        "--overwrite",
        action="store_true",
        help="replace the scale.md an earlier run wrote into --out",
    )
    p.add_argument(
        "--kiss",
        nargs="*",
        default=None,
        metavar="CASES_DIR",
        help="also time KISS-Matcher + GICP against us on these case folders",
    )


def _pair_rows(args: argparse.Namespace, out: Path) -> list[ScaleRow]:
    """Make the dense pairs ``args`` asks for (kept for the next run); time them."""
    rows = []
    for n in args.points:
        pair = out / dense_name(Path(args.case_dir).name, n, args.noise_m, args.seed)
        if not (pair / "truth.json").exists():
            print(f"making {pair.name} ...", file=sys.stderr)
            make_scale_pair(args.case_dir, pair, n, args.noise_m, args.seed)
        print(f"timing amrst register on {pair.name} ...", file=sys.stderr)
        rows.append(time_register(pair, n))
    return rows


#: Points per dense scan: fewer leave too little to register; more than a real scan
#: (50M a position) would only test the memory of the machine.
POINTS = Bounds(1_000, 100_000_000, integer=True, unit="points")


def check_options(args: argparse.Namespace) -> None:
    """Refuse options no dense scan can be made with, before anything is written.

    Raises
    ------
    InvalidInput
        A ``--points`` out of ``POINTS``, or a ``--noise-m`` or ``--seed`` out of
        the range ``amrst simulate`` takes.
    """
    from amrst.simulate.settings import check_number, check_numbers

    for n in args.points:
        check_number("points", n, cli=True, bounds=POINTS)
    check_numbers({"noise_m": args.noise_m, "seed": args.seed}, cli=True)


def check_case(case_dir: PathLike) -> bool:
    """Check the case folder to densify before any work; tell whether it is a plot.

    Reads its truth, and for a pair finds its two scans (the scans are read later).

    Raises
    ------
    InvalidInput
        A folder that is missing, holds no truth.json, or whose truth or scans a
        run would refuse.
    """
    from amrst.bench.plot import is_plot_case, read_plot_truth
    from amrst.io.cases import case_scan
    from amrst.io.truth import read_truth_document

    root = Path(case_dir)
    if not root.is_dir():
        what = "is not a folder" if root.exists() else "does not exist"
        raise InvalidInput(
            f"{root} {what}: give a case folder (target.*, source.*, truth.json) or "
            "a plot case folder."
        )
    if not (root / "truth.json").is_file():
        raise InvalidInput(
            f"{root} has no truth.json; it is not a case folder: give one that holds "
            "target.*, source.* and truth.json, or make one with 'amrst simulate'."
        )
    if is_plot_case(root):
        read_plot_truth(root)
        return True
    read_truth_document(root / "truth.json")
    for role in ("target", "source"):
        case_scan(root, role)
    return False


#: The file a run writes into --out that marks an earlier run.
SCALE_FILES = ("scale.md",)


def run_cli(args: argparse.Namespace) -> int:
    """Make the dense pairs or plots (kept for the next run), time them, print tables.

    A case whose truth lists the stems is a plot: ``amrst plot`` is timed on it.
    Everything the run needs is checked before any work.

    Returns
    -------
    int
        0 when every timed command measured, 1 when one stopped without timings
        (the tables are written all the same).
    """
    from amrst.bench.cli import check_out
    from amrst.files.atomic import make_folder, write_text_atomic
    from amrst.files.outcheck import check_outside

    check_options(args)
    plot = check_case(args.case_dir)
    check_outside(args.out, args.case_dir, "case folder")
    check_out(Path(args.out), args.overwrite, SCALE_FILES)
    if args.kiss is not None:
        from amrst.bench.kiss import kiss_case_paths

        kiss_case_paths(args.kiss or ["cases"])
    out = make_folder(args.out, "output folder")
    parts = [f"Command: `amrst bench-scale {' '.join(sys.argv[2:])}`", ""]
    rows: Sequence[ScaleRow] | Sequence[PlotScaleRow]
    if plot:
        from amrst.bench.scale_plot import plot_scale_report

        text, rows = plot_scale_report(
            args.case_dir, out, args.points, args.noise_m, args.seed
        )
        parts.append(text)
    else:
        rows = _pair_rows(args, out)
        parts += [format_scale_table(rows), ""]
    if args.kiss is not None:
        from amrst.bench.cli import TerminalProgress
        from amrst.bench.kiss import format_kiss_table, kiss_ratio

        dirs = args.kiss or ["cases"]
        parts += [format_kiss_table(kiss_ratio(dirs, reporter=TerminalProgress())), ""]
    text = "\n".join(parts)
    write_text_atomic(out / "scale.md", text)
    print(text)
    failed = [f"{out / r.name} (exit {r.exit_code})" for r in rows if not r.measured]
    if failed:
        command = "amrst plot" if plot else "amrst register"
        print(
            f"amrst bench-scale: {command} stopped without timings on "
            f"{', '.join(failed)}; run it on those scans to see why.",
            file=sys.stderr,
        )
        return 1
    return 0
