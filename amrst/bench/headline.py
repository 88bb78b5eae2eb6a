"""Summary sections: the headline (counts side by side, silent failures, speed), truth check.

One table per run (one case set): for every method the cases registered, for amrst
also how many it flagged unverified and how many it called verified while wrong (a
*silent failure*, which must stay at 0), and the median time with its ratio to
KISS-Matcher + GICP (``kiss_gicp``), the strongest pip-installable peer, measured in
the same run.
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING, Any

import numpy as np

from amrst.bench.markdown import markdown_table

if TYPE_CHECKING:
    from collections.abc import Sequence

    from amrst.bench.run import RunRecord

PEER = "kiss_gicp"


def silent_failures(runs: Sequence[RunRecord]) -> list[str]:
    """Cases where amrst said "verified" but did not register (by case, any repeat).

    Parameters
    ----------
    runs : sequence of RunRecord

    Returns
    -------
    list of str
        Case names, sorted, each once.
    """
    return sorted(
        {
            r.case
            for r in runs
            if r.method == "amrst"
            and not r.error
            and not r.success
            and bool(r.extra.get("verified", False))
        }
    )


def headline_markdown(
    agg: dict[tuple[str, str], dict[str, Any]],
    runs: Sequence[RunRecord],
    cases: list[str],
    methods: list[str],
) -> str:
    """Return the "Headline" section of summary.md.

    Parameters
    ----------
    agg : dict
        ``report.aggregate(runs)``.
    runs : sequence of RunRecord
    cases, methods : list of str

    Returns
    -------
    str
        Markdown; empty when amrst did not run.
    """
    if "amrst" not in methods:
        return ""
    rows = []
    for m in methods:
        cells = [agg[(c, m)] for c in cases if (c, m) in agg]
        ok = sum(bool(r["success"]) for r in cells)
        times = [r["time_s"] for r in cells if math.isfinite(r["time_s"])]
        med = float(np.median(times)) if times else math.nan
        ratio = _ratio(agg, cases, m)
        rows.append(
            f"| {m} | {ok}/{len(cells)} | {med:.2f} | "
            f"{'' if math.isnan(ratio) else f'{ratio:.2f}x'} |"
        )
    verified = {
        r.case
        for r in runs
        if r.method == "amrst" and bool(r.extra.get("verified", False))
    }
    silent = silent_failures(runs)
    unverified = [c for c in cases if (c, "amrst") in agg and c not in verified]
    out = [
        "\n## Headline\n\n",
        f"Median time per case and its ratio to {PEER} (KISS-Matcher + small_gicp "
        "GICP) over the same cases in this run, median of per-case ratios "
        "(below 1: faster than the peer).\n\n",
        "| method | registered | median time (s) | time / " + PEER + " |\n",
        "|---|---|---|---|\n",
        *(row + "\n" for row in rows),
        f"\namrst: {len(verified)} verified, {len(unverified)} flagged unverified "
        f"(exit 3){': ' + ', '.join(unverified) if unverified else ''}; "
        f"silent failures (verified but not registered): {len(silent)}"
        f"{': ' + ', '.join(silent) if silent else ''}.\n",
    ]
    return "".join(out)


def _ratio(
    agg: dict[tuple[str, str], dict[str, Any]], cases: list[str], m: str
) -> float:
    vals = []
    for c in cases:
        a, b = agg.get((c, m)), agg.get((c, PEER))
        if a and b and not a["error"] and not b["error"] and b["time_s"] > 0:
            vals.append(a["time_s"] / b["time_s"])
    return float(np.median(vals)) if vals else math.nan


def truth_check_markdown(
    agg: dict[tuple[str, str], dict[str, Any]], cases: list[str], method: str = "amrst"
) -> str:
    """Tabulate per case how many source points land within 2 / 4 cm of the target.

    Counted under the truth and under ``method``'s estimate, with whether the data
    prefer the estimate.
    """

    def pct(v: float) -> str:
        return f"{100 * v:.1f}%" if math.isfinite(v) else "nan"

    rows = []
    for c in cases:
        r = agg.get((c, method))
        if r is None or r["error"]:
            continue
        est = (r["within_2cm"], r["within_4cm"])
        true = (r["truth_within_2cm"], r["truth_within_4cm"])
        est_wins = [e >= t for e, t in zip(est, true, strict=True)]
        if r["success"]:
            verdict = "registered"
        elif not all(math.isfinite(v) for v in (*est, *true)):
            verdict = "n/a (an empty cloud)"
        elif all(est_wins):
            verdict = "estimate fits the data at least as well as the truth"
        elif not any(est_wins):
            verdict = "truth fits better: the method missed it"
        else:
            near, far = ("estimate", "truth") if est_wins[0] else ("truth", "estimate")
            verdict = f"mixed: the data favour the {near} at 2 cm, the {far} at 4 cm"
        rows.append([c, pct(true[0]), pct(true[1]), pct(est[0]), pct(est[1]), verdict])
    return (
        f"\n## Do the scans single out the truth? ({method})\n\n"
        "Share of source points within 2 cm and 4 cm of the target under the truth "
        f"and under {method}'s estimate. When an unregistered estimate puts at least "
        "as many points that close as the truth does, the scans alone do not single "
        "out the truth at that tolerance: no method that scores how well the clouds "
        "agree can be expected to find it there, whether the estimate lies near it "
        "or far from it.\n\n"
        + markdown_table(
            [
                "case",
                "truth <2 cm",
                "truth <4 cm",
                f"{method} <2 cm",
                f"{method} <4 cm",
                "verdict",
            ],
            rows,
        )
    )
