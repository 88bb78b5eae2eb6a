"""How well the two scans of a pair overlap in ``both_scans`` (issue 15).

For every case: the per-scan stages of both scans in two threads (as ``register``
runs them), one after the other, and each scan alone on one core (one-thread KD
queries); the minimum of 5 runs of each, alternated, summed over the cases.
``max(target, source)`` is what two cores could do at best with the two scans as
they are, one core each.

Run: .venv/bin/python docs/bench/final10/scan_overlap.py ../shared/data/cases ../shared/data/cases_field
"""

from __future__ import annotations

import sys
import time

from amrst import neighbours
from amrst.io.cases import find_cases, read_case
from amrst.params import RegistrationParams
from amrst.pipeline import analysis
from amrst.progress import NULL_REPORTER


def main() -> None:
    params = RegistrationParams()
    kd_threads = neighbours.threads()
    cases = [read_case(p) for d in sys.argv[1:] for p in find_cases(d, None)]

    def task(cloud, rep):
        return analysis.analyse_scan(cloud, params, rep)

    analysis.both_scans(task, cases[0].target, cases[0].source)  # warm up
    sums = dict.fromkeys(
        ("two threads", "one after the other", "target", "source"), 0.0
    )
    ideal = 0.0
    for case in cases:
        runs: dict[str, list[float]] = {k: [] for k in sums}
        for _ in range(5):
            t0 = time.perf_counter()
            analysis.both_scans(task, case.target, case.source)
            runs["two threads"].append(time.perf_counter() - t0)
            token = analysis.SCAN_THREADS.set(1)
            try:
                t0 = time.perf_counter()
                analysis.both_scans(task, case.target, case.source)
                runs["one after the other"].append(time.perf_counter() - t0)
                neighbours.set_threads(1)
                for role in ("target", "source"):
                    t0 = time.perf_counter()
                    task(getattr(case, role), NULL_REPORTER)
                    runs[role].append(time.perf_counter() - t0)
            finally:
                analysis.SCAN_THREADS.reset(token)
                neighbours.set_threads(kd_threads)
        for k, v in runs.items():
            sums[k] += min(v)
        ideal += max(min(runs["target"]), min(runs["source"]))
    print(f"{len(cases)} cases, per-scan stages, min of 5 runs each, summed (s):")
    for k, v in sums.items():
        print(f"  {k:22s} {v:.3f}")
    print(f"  {'max(target, source)':22s} {ideal:.3f}")
    print(
        f"two threads: {sums['one after the other'] / sums['two threads']:.2f}x faster "
        f"than one after the other; the best two cores could do: "
        f"{sums['one after the other'] / ideal:.2f}x"
    )


if __name__ == "__main__":
    main()
