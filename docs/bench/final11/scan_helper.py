"""The per-scan stages: two threads (as landed) against a warm helper process for the source.

Variants, each case 5 times, the order alternating, the minimum counting:

- ``threads``: ``both_scans`` as ``amrst.register`` runs it (small_gicp queries on two
  OpenMP threads);
- ``helper``: the source scan analysed in a warm ``forkserver`` process while this
  process analyses the target, both with ONE OpenMP thread (``neighbours.set_threads(1)``);
  the analysis comes back without its neighbour table and cloud (0.4 MB pickled
  for case 01 instead of the table's megabytes);
- ``threads1``: ``both_scans`` with one OpenMP thread per query (what the helper's
  setting does to the threads alone).

Run: .venv/bin/python docs/bench/final11/scan_helper.py ../shared/data/cases ../shared/data/cases_field
"""

from __future__ import annotations

import multiprocessing as mp
import sys
import time
from dataclasses import replace

import numpy as np

from amrst import neighbours
from amrst.io.cases import find_cases, read_case
from amrst.params import RegistrationParams
from amrst.pipeline.analysis import analyse_scan, both_scans

PARAMS = RegistrationParams()


def _portable(cloud):
    return cloud.xyz, cloud.offset, dict(cloud.attributes), cloud.name


def _work(parts):
    from amrst.types import Cloud

    neighbours.set_threads(1)
    an = analyse_scan(Cloud(*parts), PARAMS)
    pre = replace(an.pre, neighbours=None)
    scene_pre = None if an.scene_pre is None else replace(an.scene_pre, neighbours=None)
    return replace(an, pre=pre, scene_pre=scene_pre, cloud=None)


def main() -> None:
    cases = [read_case(p) for d in sys.argv[1:] for p in find_cases(d, None)]
    pool = mp.get_context("forkserver").Pool(1)
    pool.apply(_work, (_portable(cases[0].source),))

    def threads(c):
        return both_scans(
            lambda cl, rep: analyse_scan(cl, PARAMS, rep), c.target, c.source
        )

    def helper(c):
        neighbours.set_threads(1)
        job = pool.apply_async(_work, (_portable(c.source),))
        try:
            tgt = analyse_scan(c.target, PARAMS)
        finally:
            neighbours.set_threads(2)
        return tgt, replace(job.get(), cloud=c.source)

    def threads1(c):
        neighbours.set_threads(1)
        try:
            return threads(c)
        finally:
            neighbours.set_threads(2)

    fns = {"threads": threads, "helper": helper, "threads1": threads1}
    best: dict[str, list[float]] = {k: [] for k in fns}
    for c in cases:
        runs: dict[str, list[float]] = {k: [] for k in fns}
        for i in range(5):
            for name in list(fns) if i % 2 == 0 else list(fns)[::-1]:
                t0 = time.perf_counter()
                fns[name](c)
                runs[name].append(time.perf_counter() - t0)
        for k in fns:
            best[k].append(min(runs[k]))
        print(c.name[:30], {k: round(min(v) * 1000, 1) for k, v in runs.items()})
    ref = np.array(best["threads"])
    for k in fns:
        t = np.array(best[k])
        print(
            f"{k}: sum {t.sum():.3f} s; median per case / threads {np.median(t / ref):.3f}"
        )
    pool.close()


if __name__ == "__main__":
    main()
