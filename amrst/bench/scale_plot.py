"""Scale benchmark on plot cases: every scan densified, ``amrst plot`` timed whole.

:func:`make_scale_plot` writes every scan of a plot case (``target.ply`` +
``source.ply``, or ``scan_1.ply`` ... ``scan_N.ply``) with ``n_points`` points, made by
:func:`amrst.bench.densify.densify` in the scan's own frame, so the case's truth still
holds; the folder written is itself a plot case. :func:`time_plot` runs ``amrst plot``
on its scans in a child process, as a user does, and returns the whole time, the
child's peak resident memory, the time of each stage, and every scan's pose and the
inventory scored against the truth (``amrst.bench.plot``).

The stages are read from what the command hands over: ``plot.json`` times the reading
and the registration (``read``, ``analyse``, ``links``, ``joint``); its progress lines
on stderr, each stamped with the seconds since the run began, date the start of the
run, and its closing line the end of the inventory and the writing.
"""

from __future__ import annotations

import csv
import json
import os
import re
import sys
import tempfile
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from amrst.bench.child import run_amrst
from amrst.bench.densify import dense_name, densify
from amrst.bench.markdown import markdown_table
from amrst.bench.plot import PLOT, PlotRecord, _score_poses
from amrst.io.cases import plot_scan_files

if TYPE_CHECKING:
    from collections.abc import Sequence

    from amrst.bench.plot import PlotCase
    from amrst.types import Transform

PathLike = str | os.PathLike[str]
#: Stages of ``amrst plot`` in the order it runs them (the table's columns).
PLOT_STAGES = ("start", "read", "analyse", "links", "joint", "inventory")
# A progress line of the terminal reporter: seconds since it was made, the message.
_STAMPED = re.compile(r"^\s*(\d+(?:\.\d+)?)s ")
# The command's closing line, written once the inventory is on disk.
_CLOSING = re.compile(r": \d+ trees; \d+ of \d+ scans registered")


def make_scale_plot(
    case_dir: PathLike,
    out_dir: PathLike,
    n_points: int,
    noise_m: float = 0.003,
    seed: int = 0,
) -> Path:
    """Write every scan of a plot case with ``n_points`` points, and its truth.

    Parameters
    ----------
    case_dir : path
        A plot case folder (see :func:`amrst.bench.plot.read_plot_case`).
    out_dir : path
        Created when missing; the scans keep their file names (binary PLY).
    n_points : int
        Points per scan.
    noise_m : float
    seed : int
        Scan k (1-based) uses ``seed + k - 1``.

    Returns
    -------
    Path
        The folder written.
    """
    from amrst import io
    from amrst.bench.plot import read_plot_case
    from amrst.files.atomic import make_folder, write_json_atomic

    case = read_plot_case(case_dir)
    out = make_folder(out_dir, "scale plot folder")
    for k, cloud in enumerate(case.clouds):
        name = f"{Path(cloud.name).stem}.ply"
        io.write(out / name, densify(cloud, n_points, noise_m, seed + k))
    truth = json.loads((Path(case_dir) / "truth.json").read_text())
    truth.update(
        densified_from=str(case_dir),
        densify_points=n_points,
        densify_noise_m=noise_m,
        densify_seed=seed,
    )
    write_json_atomic(out / "truth.json", truth, indent=1)
    return out


@dataclass(frozen=True, slots=True)
class PlotScaleRow:
    """One whole ``amrst plot`` command on one densified plot.

    ``stages`` (s): ``start`` interpreter start and imports; ``read`` reading the
    scans, ``analyse``, ``links``, ``joint`` the registration (``plot.json``);
    ``inventory`` the inventory and writing its files. ``progress``: the command's
    stderr lines, each with the seconds since the command started.
    """

    name: str
    n_scans: int
    n_points: int  # per scan
    wall_s: float
    peak_mb: float
    exit_code: int
    stages: dict[str, float]
    record: PlotRecord
    progress: tuple[tuple[float, str], ...]

    @property
    def measured(self) -> bool:
        """Whether the command ran to the end and wrote its timings."""
        return bool(self.stages)


def time_plot(plot_dir: PathLike, extra: Sequence[str] = ()) -> PlotScaleRow:
    """Run ``amrst plot`` on a plot case folder in a child process; score it.

    Parameters
    ----------
    plot_dir : path
        A plot case folder (scans and ``truth.json``), e.g. from
        :func:`make_scale_plot`.
    extra : sequence of str
        More ``amrst plot`` arguments.

    Returns
    -------
    PlotScaleRow
        Peak memory is the child's maximum resident set size (``wait4``). The scans
        are read again after the command, to score it, one plot at a time.
    """
    from amrst.bench.plot import read_plot_case

    folder = Path(plot_dir)
    truth = json.loads((folder / "truth.json").read_text())
    files = plot_scan_files(folder)
    with tempfile.TemporaryDirectory(prefix="amrst-scale-plot-") as tmp:
        child = run_amrst("plot", *map(str, files), "--out", tmp, *extra)
        doc_path, csv_path = Path(tmp) / "plot.json", Path(tmp) / "trees.csv"
        doc = json.loads(doc_path.read_text()) if doc_path.exists() else None
        trees = _listed_trees(csv_path) if csv_path.exists() else None
    case = read_plot_case(folder)
    record = _score(case, doc, trees, child.stderr)
    n = int(truth.get("densify_points", 0)) or max(len(c) for c in case.clouds)
    return PlotScaleRow(
        folder.name,
        len(files),
        n,
        child.wall_s,
        child.peak_mb,
        child.exit_code,
        {} if doc is None else plot_stages(doc["timings_s"], child.stderr),
        record,
        child.stderr,
    )


def plot_stages(
    timings: dict[str, float], lines: Sequence[tuple[float, str]]
) -> dict[str, float]:
    """Seconds of each stage of ``PLOT_STAGES`` (those the output dates).

    ``timings``: ``plot.json``'s ``timings_s``; ``lines``: stderr lines with the
    seconds since the command started.
    """
    stages = {k: float(timings[k]) for k in ("read", "analyse", "links", "joint")}
    stamped = [(t, _STAMPED.match(text)) for t, text in lines]
    first = next(((t, m) for t, m in stamped if m is not None), None)
    if first is None:  # --quiet: no progress lines
        return stages
    start = first[0] - float(first[1].group(1))
    stages["start"] = start
    closing = [t for t, text in lines if _CLOSING.search(text)]
    if closing:
        stages["inventory"] = closing[-1] - start - float(timings["total"])
    return stages


def _listed_trees(path: Path) -> tuple[np.ndarray, list[str], list[str]]:
    """trees.csv as rows (x, y, z, dbh, height), DBH flags and height flags."""
    with path.open(newline="") as f:
        rows = list(csv.DictReader(f))

    def num(text: str) -> float:
        return float(text) if text else float("nan")

    listed = np.array(
        [[num(r[c]) for c in ("x_m", "y_m", "z_m", "dbh_m", "height_m")] for r in rows],
        dtype=float,
    ).reshape(-1, 5)
    return (
        listed,
        [r["dbh_quality"] for r in rows],
        [r["height_flag"] for r in rows],
    )


def _score(
    case: PlotCase,
    doc: dict[str, Any] | None,
    trees: tuple[np.ndarray, list[str], list[str]] | None,
    lines: Sequence[tuple[float, str]],
) -> PlotRecord:
    """Score the command's poses and inventory against the case's truth."""
    from amrst.bench.plot import score_inventory

    record = PlotRecord(case.name, PLOT, len(case.clouds))
    if doc is None:
        record.error = lines[-1][1] if lines else "no plot.json written"
        return record
    poses: list[Transform | None] = [
        None if s["T_reference_scan"] is None else np.array(s["T_reference_scan"])
        for s in doc["scans"]
    ]
    _score_poses(case, record, poses)
    if trees is not None:
        record.inventory = score_inventory(trees[0], trees[1], case.stems, trees[2])
    return record


def _fmt(value: float | None, scale: float = 1.0, digits: int = 1) -> str:
    return (
        "-"
        if value is None or not np.isfinite(value)
        else f"{scale * value:.{digits}f}"
    )


def format_plot_scale_table(rows: Sequence[PlotScaleRow]) -> str:
    """Markdown: per plot, seconds per stage, the whole command, memory, the scores."""
    head = [
        "plot",
        "scans x points",
        *PLOT_STAGES,
        "command s",
        "peak MB",
        "within 1 deg / 5 cm",
        "worst deg / cm",
        "trees found",
        "exit",
    ]
    table = []
    for r in rows:
        rec = r.record
        worst_deg = max(rec.rotation_error_deg, default=float("nan"))
        worst_cm = max(rec.gt_rmse_m, default=float("nan"))
        inv = rec.inventory
        cells = [
            r.name,
            f"{r.n_scans} x {r.n_points:,}",
            *(_fmt(r.stages.get(s)) for s in PLOT_STAGES),
            _fmt(r.wall_s),
            f"{r.peak_mb:,.0f}",
            f"{rec.registered}/{r.n_scans - 1}",
            f"{_fmt(worst_deg, digits=3)} / {_fmt(worst_cm, 100)}",
            "-" if inv is None else f"{inv.found}/{inv.n_true}",
            str(r.exit_code),
        ]
        table.append(cells)
    return markdown_table(head, table).rstrip("\n")


def plot_scale_report(
    case_dir: PathLike,
    out: Path,
    points: Sequence[int],
    noise_m: float = 0.003,
    seed: int = 0,
) -> tuple[str, list[PlotScaleRow]]:
    """Make the dense plots (kept for the next run), time them.

    Returns
    -------
    text : str
        The Markdown: the table and each run's progress lines.
    rows : list of PlotScaleRow
    """
    rows = []
    for n in points:
        plot = out / dense_name(Path(case_dir).name, n, noise_m, seed)
        if not (plot / "truth.json").exists():
            print(f"making {plot.name} ...", file=sys.stderr)
            make_scale_plot(case_dir, plot, n, noise_m, seed)
        print(f"timing amrst plot on {plot.name} ...", file=sys.stderr)
        rows.append(time_plot(plot))
    parts = [format_plot_scale_table(rows), ""]
    for r in rows:
        parts += [f"Progress of `amrst plot` on {r.name} (s since start):", "", "```"]
        parts += [f"{t:7.1f}  {text}" for t, text in r.progress]
        parts += ["```", ""]
    return "\n".join(parts), rows
