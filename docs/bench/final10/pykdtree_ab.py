"""pykdtree (commit 242ed3a, reverted) against small_gicp, alternated in one process.

The swapped modules come from that commit:

    mkdir -p /tmp/pyk
    git show 242ed3a:amrst/kdtree.py > /tmp/pyk/kdtree.py
    git show 242ed3a:amrst/neighbours.py > /tmp/pyk/neighbours_pyk.py

Run: .venv/bin/python docs/bench/final10/pykdtree_ab.py scans|register CASE_DIR...
Each case runs 5 times per backend, the order alternating; the minimum counts.
The stages import ``amrst.neighbours`` inside their functions, so replacing it in
``sys.modules`` between runs swaps the backend.
"""

from __future__ import annotations

import importlib.util
import sys
import time

import numpy as np

import amrst.neighbours as small_gicp_neighbours
from amrst.io.cases import find_cases, read_case
from amrst.params import RegistrationParams
from amrst.pipeline import analysis, register


def _load(name: str, path: str):
    spec = importlib.util.spec_from_file_location(name, path)
    module = importlib.util.module_from_spec(spec)
    sys.modules[name] = module
    spec.loader.exec_module(module)
    return module


def main() -> None:
    mode = sys.argv[1]  # "scans" (both_scans alone) or "register"
    kdtree = _load("amrst.kdtree", "/tmp/pyk/kdtree.py")
    pyk_neighbours = _load("amrst_neighbours_pyk", "/tmp/pyk/neighbours_pyk.py")
    sys.modules["amrst.neighbours"] = small_gicp_neighbours
    cases = [read_case(p) for d in sys.argv[2:] for p in find_cases(d, None)]
    params = RegistrationParams()
    one_scan = analysis._stop_sibling_on_error

    def one_scan_sharing(fn, item, rep, shared):
        with kdtree.sharing_cores():  # as 242ed3a's both_scans did
            return one_scan(fn, item, rep, shared)

    def use(which: str) -> None:
        pyk = which == "pykdtree"
        sys.modules["amrst.neighbours"] = (
            pyk_neighbours if pyk else small_gicp_neighbours
        )
        analysis._stop_sibling_on_error = one_scan_sharing if pyk else one_scan

    def task(cloud, rep):
        return analysis.analyse_scan(cloud, params, rep)

    for which in ("small_gicp", "pykdtree"):
        use(which)
        register(cases[0].target, cases[0].source)
    best: dict[str, list[float]] = {"small_gicp": [], "pykdtree": []}
    for case in cases:
        runs: dict[str, list[float]] = {k: [] for k in best}
        for r in range(5):
            for which in list(best) if r % 2 == 0 else list(best)[::-1]:
                use(which)
                if mode == "scans":
                    t0 = time.perf_counter()
                    analysis.both_scans(task, case.target, case.source)
                    runs[which].append(time.perf_counter() - t0)
                else:
                    timings = register(case.target, case.source).timings
                    runs[which].append(timings["total"] - timings.get("metrics", 0.0))
        for which, times in runs.items():
            best[which].append(min(times))
    sg, pk = np.array(best["small_gicp"]), np.array(best["pykdtree"])
    print(
        f"{mode}: sum small_gicp {sg.sum():.3f} s, pykdtree {pk.sum():.3f} s; "
        f"median {np.median(sg):.4f} / {np.median(pk):.4f} s; "
        f"median per-case pykdtree / small_gicp {np.median(pk / sg):.3f}"
    )


if __name__ == "__main__":
    main()
