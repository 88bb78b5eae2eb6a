"""Benchmark plots (matplotlib Agg): accuracy and time per case, readable alone."""

from __future__ import annotations

import math
from typing import TYPE_CHECKING, Any

import numpy as np

from amrst.files.atomic import write_text_atomic
from amrst.results.report_images import new_figure, png_bytes

if TYPE_CHECKING:
    from pathlib import Path

_MARKERS = "osD^vP*X<>"


def _figure(n_cases: int) -> tuple[Any, Any]:
    fig = new_figure(max(8.0, 0.55 * n_cases + 3.0), 5.5)
    return fig, fig.add_subplot()


def _save(fig: Any, path: Path) -> Path:
    write_text_atomic(path, png_bytes(fig, dpi=110))
    return path


def _per_case(
    ax: Any,
    agg: dict[tuple[str, str], dict[str, Any]],
    cases: list[str],
    methods: list[str],
    key: str,
) -> float:
    """One marker per case and method, methods side by side; failures at the top."""
    values = [
        agg[k][key] for k in agg if math.isfinite(agg[k][key]) and agg[k][key] > 0
    ]
    top = max(values) * 3.0 if values else 1.0
    width = 0.8 / max(len(methods), 1)
    x = np.arange(len(cases))
    for j, m in enumerate(methods):
        xs, ys, fx = [], [], []
        for i, c in enumerate(cases):
            row = agg.get((c, m))
            if row is None:
                continue
            v = row[key]
            if row["error"] or not math.isfinite(v):
                fx.append(i + (j - (len(methods) - 1) / 2) * width)
            else:
                xs.append(i + (j - (len(methods) - 1) / 2) * width)
                ys.append(max(v, 1e-6))
        color = f"C{j % 10}"
        ax.scatter(
            xs, ys, marker=_MARKERS[j % len(_MARKERS)], color=color, label=m, s=36
        )
        if fx:
            ax.scatter(fx, [top] * len(fx), marker="x", color=color, s=40)
    ax.set_yscale("log")
    ax.set_xticks(x, cases, rotation=60, ha="right", fontsize=8)
    ax.set_xlim(-0.6, len(cases) - 0.4)
    ax.grid(True, which="major", axis="y", alpha=0.3)
    for i in range(1, len(cases)):
        ax.axvline(i - 0.5, color="0.9", lw=0.8, zorder=0)
    return top


def write_plots(
    out: Path,
    agg: dict[tuple[str, str], dict[str, Any]],
    cases: list[str],
    methods: list[str],
) -> list[Path]:
    """``accuracy.png`` (gt_rmse per case, log scale, 5 cm line) and ``time.png``.

    Parameters
    ----------
    out : Path
        Output folder.
    agg : dict
        :func:`amrst.bench.report.aggregate` of the runs.
    cases, methods : list of str

    Returns
    -------
    list of Path
    """
    fig, ax = _figure(len(cases))
    top = _per_case(ax, agg, cases, methods, "gt_rmse_m")
    ax.axhline(0.05, color="k", ls="--", lw=1.2)
    ax.text(
        -0.5,
        0.05,
        " success: gt_rmse < 5 cm (and rotation < 1 deg)",
        va="bottom",
        fontsize=8,
    )
    ax.set_ylabel("gt_rmse (m): source points moved by estimate vs truth")
    raised = any(row["error"] for row in agg.values())
    ax.set_title(
        "Registration error per case (lower is better)"
        + (f"; x at {top:.3g} m = the method raised" if raised else "")
    )
    ax.legend(loc="upper left", bbox_to_anchor=(1.0, 1.0), fontsize=9)
    files = [_save(fig, out / "accuracy.png")]
    fig, ax = _figure(len(cases))
    _per_case(ax, agg, cases, methods, "time_s")
    ax.set_ylabel("compute time of the method (s)")
    ax.set_title("Registration time per case (lower is faster; log scale)")
    ax.legend(loc="upper left", bbox_to_anchor=(1.0, 1.0), fontsize=9)
    files.append(_save(fig, out / "time.png"))
    return files
