"""Our compute and KISS-Matcher + GICP per case under one OpenMP wait policy.

small_gicp and KISS-Matcher share one libgomp; its threads spin after each parallel
region unless ``OMP_WAIT_POLICY=passive``. The policy is read when libgomp loads, so
each run is its own process; alternate them:

    for i in 1 2 3; do
      .venv/bin/python docs/bench/final11/omp_policy.py SETS... >> omp.jsonl
      OMP_WAIT_POLICY=passive .venv/bin/python docs/bench/final11/omp_policy.py SETS... >> omp.jsonl
    done

Each case: 3 runs of each method, the minimum counting; one JSON line per run.
"""

from __future__ import annotations

import json
import os
import sys
import time

from amrst.baselines._common import local_pair
from amrst.bench.kiss import kiss_gicp
from amrst.io.cases import find_cases, read_case
from amrst.pipeline import register


def main() -> None:
    cases = [read_case(p) for d in sys.argv[1:] for p in find_cases(d, None)]
    tgt, src, _ = local_pair(cases[0].target, cases[0].source)
    register(cases[0].target, cases[0].source)
    kiss_gicp(tgt, src)
    ours, kiss = [], []
    for c in cases:
        tgt, src, _ = local_pair(c.target, c.source)
        o, k = [], []
        for _ in range(3):
            t = register(c.target, c.source).timings
            o.append(t["total"] - t.get("metrics", 0.0))
            t0 = time.perf_counter()
            kiss_gicp(tgt, src)
            k.append(time.perf_counter() - t0)
        ours.append(min(o))
        kiss.append(min(k))
    policy = os.environ.get("OMP_WAIT_POLICY", "default")
    print(json.dumps({"policy": policy, "ours": ours, "kiss": kiss}))


if __name__ == "__main__":
    main()
