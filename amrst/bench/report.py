"""Benchmark outputs: results.csv, results.json, summary.md (tables) and the plots.

Every file is written through a temp file and ``os.replace``, so a reader never sees
a half-written table. The summary reports, per method, the success count (rotation
error < 1 deg and gt_rmse < 5 cm), median errors and times; per case, the paper's
RMSE / Hausdorff table and times; the median per-case speed ratio of amrst against
each other method from the same run; and the machine it ran on.
"""

from __future__ import annotations

import csv
import io
import json
import math
import os
import platform
from datetime import datetime
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from amrst.bench.headline import headline_markdown, truth_check_markdown
from amrst.bench.markdown import markdown_table
from amrst.files.atomic import write_text_atomic

if TYPE_CHECKING:
    from collections.abc import Sequence

    from amrst.bench.run import RunRecord

SUCCESS_RULE = "rotation error < 1 deg and gt_rmse < 0.05 m"
_CSV_FIELDS = [
    "case",
    "method",
    "repeat",
    "success",
    "rotation_error_deg",
    "translation_error_m",
    "gt_rmse_m",
    "rmse_m",
    "rmse_overlap_m",
    "hausdorff_m",
    "hausdorff_p95_m",
    "overlap_fraction",
    "within_2cm",
    "within_4cm",
    "truth_within_2cm",
    "truth_within_4cm",
    "time_s",
    "wall_s",
    "fitness",
    "inlier_rmse_m",
    "iterations",
    "converged",
    "n_target",
    "n_source",
    "error",
]


def _version(module: str) -> str:
    try:
        mod = __import__(module)
        return str(getattr(mod, "__version__", "?"))
    except Exception:  # a missing optional library is "not installed", not a crash
        return "not installed"


def machine_info() -> dict[str, Any]:
    """CPU model, cores, Python and library versions, and the date, for the summary."""
    cpu = "unknown"
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                cpu = line.split(":", 1)[1].strip()
                break
    except OSError:
        cpu = platform.processor() or "unknown"
    usable = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else None
    return {
        "cpu": cpu,
        "cores": os.cpu_count(),
        "usable_cores": usable,
        "platform": platform.platform(),
        "python": platform.python_version(),
        "versions": {
            m: _version(m) for m in ("amrst", "numpy", "scipy", "open3d", "matplotlib")
        },
        "date": datetime.now().astimezone().isoformat(timespec="seconds"),
    }


def fmt(value: float | None) -> str:
    """Format a table cell: 3 decimals below 10, fewer above, ``-`` when missing."""
    if value is None or (isinstance(value, float) and not math.isfinite(value)):
        return "-"
    v = float(value)
    if abs(v) >= 100:
        return f"{v:.0f}"
    if abs(v) >= 10:
        return f"{v:.1f}"
    return f"{v:.3f}"


def aggregate(runs: Sequence[RunRecord]) -> dict[tuple[str, str], dict[str, Any]]:
    """Median over repeats of each (case, method): errors, metrics, time, success.

    Returns
    -------
    dict
        Keyed by ``(case, method)``; ``success`` is true when most repeats succeeded,
        ``error`` is the first error text (empty when every repeat ran).
    """
    groups: dict[tuple[str, str], list[RunRecord]] = {}
    for run in runs:
        groups.setdefault((run.case, run.method), []).append(run)
    out = {}
    for key, group in groups.items():
        row: dict[str, Any] = {}
        for name in (
            "rotation_error_deg",
            "translation_error_m",
            "gt_rmse_m",
            "rmse_m",
            "hausdorff_m",
            "time_s",
            "within_2cm",
            "within_4cm",
            "truth_within_2cm",
            "truth_within_4cm",
        ):
            values = np.array([getattr(r, name) for r in group], dtype=float)
            row[name] = (
                float(np.median(values)) if np.isfinite(values).any() else math.nan
            )
        row["success"] = sum(r.success for r in group) * 2 > len(group)
        row["error"] = next((r.error for r in group if r.error), "")
        out[key] = row
    return out


def _median(values: list[float]) -> float:
    finite = [v for v in values if math.isfinite(v)]
    return float(np.median(finite)) if finite else math.nan


def speed_ratios(
    agg: dict[tuple[str, str], dict[str, Any]],
    cases: list[str],
    methods: list[str],
    ref: str = "amrst",
) -> dict[str, tuple[float, int]]:
    """Median over cases of ``time(method) / time(ref)`` where both ran cleanly."""
    ratios = {}
    for m in methods:
        if m == ref:
            continue
        per_case = []
        for c in cases:
            a, b = agg.get((c, ref)), agg.get((c, m))
            if a and b and not a["error"] and not b["error"] and a["time_s"] > 0:
                per_case.append(b["time_s"] / a["time_s"])
        ratios[m] = (_median(per_case), len(per_case))
    return ratios


def summary_markdown(
    runs: Sequence[RunRecord],
    cases: list[str],
    methods: list[str],
    meta: dict[str, Any],
) -> str:
    """Write the summary.md text: method table, per-case tables, speed ratios, machine."""
    agg = aggregate(runs)
    n = len(cases)
    out = ["# AMRST benchmark\n\n"]
    out.append(
        f"{n} cases x {len(methods)} methods x {meta.get('repeat', 1)} repeat(s); "
        f"registered = {SUCCESS_RULE}. Times are the seconds each method reports for "
        f"its own run (clouds already in memory, libraries loaded), median over "
        f"repeats.\n\n"
    )
    rows = []
    for m in methods:
        cells = [agg[(c, m)] for c in cases if (c, m) in agg]
        ok = sum(r["success"] for r in cells)
        failed = sum(bool(r["error"]) for r in cells)
        rows.append(
            [m, f"{ok}/{len(cells)}"]
            + [
                fmt(_median([r[k] for r in cells]))
                for k in (
                    "rotation_error_deg",
                    "translation_error_m",
                    "gt_rmse_m",
                    "time_s",
                )
            ]
            + [
                fmt(sum(r["time_s"] for r in cells if math.isfinite(r["time_s"]))),
                str(failed),
            ]
        )
    out.append(headline_markdown(agg, runs, cases, methods))
    out.append("\n## Per method\n\n")
    out.append(
        markdown_table(
            [
                "method",
                "registered",
                "median rot err (deg)",
                "median trans err (m)",
                "median gt_rmse (m)",
                "median time (s)",
                "total time (s)",
                "raised",
            ],
            rows,
        )
    )
    if "amrst" in methods and len(methods) > 1:
        out.append("\n## Speed of amrst\n\n")
        out.append(
            "Median over cases of time(method) / time(amrst), same run "
            "(above 1: amrst is faster):\n\n"
        )
        ratio_rows = [
            [m, f"{fmt(r)}x", str(k)]
            for m, (r, k) in speed_ratios(agg, cases, methods).items()
        ]
        out.append(markdown_table(["method", "time ratio", "cases"], ratio_rows))
    header = ["case"] + [f"{m} {q}" for m in methods for q in ("RMSE", "HD")]
    rows = [
        [c]
        + [
            fmt(agg.get((c, m), {}).get(q))
            for m in methods
            for q in ("rmse_m", "hausdorff_m")
        ]
        for c in cases
    ]
    out.append("\n## RMSE and Hausdorff distance (m) per case (paper Table II)\n\n")
    out.append(
        "Nearest-neighbour RMSE of the moved source to the target, and the "
        "symmetric Hausdorff distance.\n\n"
    )
    out.append(markdown_table(header, rows))

    def cell(c: str, m: str, key: str) -> str:
        r = agg.get((c, m))
        if r is None:
            return ""
        if r["error"]:
            return "error"
        return fmt(r[key]) + (" ok" if key == "gt_rmse_m" and r["success"] else "")

    out.append("\n## gt_rmse (m) per case (ok = registered)\n\n")
    out.append(
        markdown_table(
            ["case", *methods],
            [[c] + [cell(c, m, "gt_rmse_m") for m in methods] for c in cases],
        )
    )
    if "amrst" in methods:
        out.append(truth_check_markdown(agg, cases))
    out.append("\n## Time (s) per case (paper Table III)\n\n")
    out.append(
        markdown_table(
            ["case", *methods],
            [[c] + [cell(c, m, "time_s") for m in methods] for c in cases],
        )
    )
    errors = [r for r in runs if r.error]
    if errors:
        out.append("\n## Errors\n\n")
        out.extend(
            f"- {r.case} / {r.method} (repeat {r.repeat}): {r.error}\n" for r in errors
        )
    versions = ", ".join(f"{k} {v}" for k, v in meta.get("versions", {}).items())
    out.append("\n## Machine\n\n")
    out.append(
        f"- CPU: {meta.get('cpu')} ({meta.get('cores')} cores, "
        f"{meta.get('usable_cores')} usable)\n- {meta.get('platform')}, Python "
        f"{meta.get('python')}\n- {versions}\n- date: {meta.get('date')}\n"
        f"- whole run: {fmt(meta.get('wall_s'))} s\n"
        f"- command: `{meta.get('command') or '(library call)'}`\n"
    )
    return "".join(out)


def results_csv(runs: Sequence[RunRecord]) -> str:
    """One row per run; stage timings as ``t_<stage>`` columns."""
    stages = sorted({s for r in runs for s in r.timings})
    buf = io.StringIO()
    writer = csv.writer(buf, lineterminator="\n")
    writer.writerow(_CSV_FIELDS + [f"t_{s}" for s in stages])
    for r in runs:
        d = r.as_dict()
        writer.writerow(
            [d[f] for f in _CSV_FIELDS] + [r.timings.get(s, "") for s in stages]
        )
    return buf.getvalue()


def _json_safe(value: Any) -> Any:
    if isinstance(value, float) and not math.isfinite(value):
        return None
    if isinstance(value, dict):
        return {k: _json_safe(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_json_safe(v) for v in value]
    if isinstance(value, np.generic):
        return value.item()
    return value


def write_outputs(
    out: Path,
    runs: Sequence[RunRecord],
    cases: list[str],
    methods: list[str],
    meta: dict[str, Any],
    *,
    final: bool,
    plots: bool = True,
) -> list[Path]:
    """Write results.csv and results.json; when ``final``, also summary.md and plots.

    Returns
    -------
    list of Path
        The files written.
    """
    files = [out / "results.csv", out / "results.json"]
    write_text_atomic(files[0], results_csv(runs))
    doc = {
        "meta": meta,
        "cases": cases,
        "methods": methods,
        "runs": [r.as_dict() for r in runs],
    }
    write_text_atomic(files[1], json.dumps(_json_safe(doc), indent=1) + "\n")
    if final:
        files.append(out / "summary.md")
        write_text_atomic(files[-1], summary_markdown(runs, cases, methods, meta))
        if plots and runs:
            from amrst.bench.plots import write_plots

            files += write_plots(out, aggregate(runs), cases, methods)
    return files
