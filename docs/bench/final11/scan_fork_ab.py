"""A forked child per registration for the source scan (``scan_fork.patch``) against two threads.

Apply the patch first (``git apply docs/bench/final11/scan_fork.patch``): it adds
``amrst/pipeline/scan_fork.py`` and routes ``amrst.register`` through it; the
environment picks the path at each call (``AMRST_SCAN_PROCESS=0``: the two threads;
``AMRST_TRIM=1``: ``malloc_trim(0)`` before the fork). Each case 5 times per
variant, the order alternating, the minimum counting.

Run: .venv/bin/python docs/bench/final11/scan_fork_ab.py ../shared/data/cases ../shared/data/cases_field
"""

from __future__ import annotations

import os
import sys

import numpy as np

from amrst.io.cases import find_cases, read_case
from amrst.pipeline import register

VARIANTS = {
    "threads": {"AMRST_SCAN_PROCESS": "0", "AMRST_TRIM": "0"},
    "fork": {"AMRST_SCAN_PROCESS": "1", "AMRST_TRIM": "0"},
    "fork+trim": {"AMRST_SCAN_PROCESS": "1", "AMRST_TRIM": "1"},
}


def compare(variants: dict[str, dict[str, str]]) -> None:
    """Time ``register`` on the cases of ``sys.argv[1:]`` under each environment."""
    cases = [read_case(p) for d in sys.argv[1:] for p in find_cases(d, None)]
    register(cases[0].target, cases[0].source)
    best: dict[str, list[float]] = {k: [] for k in variants}
    for c in cases:
        runs: dict[str, list[float]] = {k: [] for k in variants}
        for i in range(5):
            for name in list(variants) if i % 2 == 0 else list(variants)[::-1]:
                os.environ.update(variants[name])
                t = register(c.target, c.source).timings
                runs[name].append(t["total"] - t["metrics"])
        for k in variants:
            best[k].append(min(runs[k]))
        print(c.name[:30], {k: round(min(v) * 1000, 1) for k, v in runs.items()})
    ref = np.array(best["threads"])
    for k in variants:
        r = np.array(best[k]) / ref
        print(
            f"{k}: sum {sum(best[k]):.3f} s; per case / threads median {np.median(r):.3f}"
            f" (cases {np.median(r[:20]):.3f}, field {np.median(r[20:]):.3f})"
        )


if __name__ == "__main__":
    compare(VARIANTS)
