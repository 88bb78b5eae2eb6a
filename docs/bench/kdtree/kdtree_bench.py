"""pykdtree against small_gicp (amrst.kdtree): build + k=32 query of every point,
one and two threads, and how much a Python thread beside the query gets to run.

Run: .venv/bin/python docs/bench/kdtree/kdtree_bench.py [CASE_DIR]
(default: ../shared/data/cases/08_treels-pine-normal, densified to 200k and 2M).
"""

from __future__ import annotations

import sys
import threading
import time

import numpy as np
import small_gicp

from amrst import kdtree
from amrst.io.cases import read_case


def _spin_rate(fn) -> tuple[float, float]:
    """Seconds of ``fn`` and the millions of loop turns per second a Python thread made
    beside it (a query that holds the GIL leaves it almost none)."""
    count, stop = [0], [False]

    def spin() -> None:
        while not stop[0]:
            count[0] += 1

    t = threading.Thread(target=spin)
    t.start()
    t0 = time.perf_counter()
    fn()
    dt = time.perf_counter() - t0
    stop[0] = True
    t.join()
    return dt, count[0] / dt / 1e6


def main() -> None:
    case = sys.argv[1] if len(sys.argv) > 1 else "../shared/data/cases/08_treels-pine-normal"
    pts = np.ascontiguousarray(read_case(case).target.xyz, dtype=np.float64)
    _, setter = kdtree._pykdtree()
    rng = np.random.default_rng(0)
    print("| points | threads | small_gicp s | pykdtree s | ratio |")
    print("|---|---|---|---|---|")
    for n in (len(pts), 200_000, 2_000_000):
        cloud = pts if n == len(pts) else np.ascontiguousarray(
            np.repeat(pts, n // len(pts) + 1, axis=0)[:n] + rng.normal(0, 0.003, (n, 3))
        )
        for th in (1, 2):
            ts, tp = [], []
            for _ in range(3 if n > 500_000 else 7):
                t0 = time.perf_counter()
                tree = small_gicp.KdTree(cloud, num_threads=th)
                tree.batch_knn_search(cloud, 32, num_threads=th)
                ts.append(time.perf_counter() - t0)
                setter(th)
                t0 = time.perf_counter()
                kdtree._PyKdTree(cloud).knn(cloud, 32, th)
                tp.append(time.perf_counter() - t0)
            print(f"| {n:,} | {th} | {min(ts):.4f} | {min(tp):.4f} | {min(tp) / min(ts):.2f} |")
    sg = small_gicp.KdTree(pts, num_threads=1)
    pk = kdtree._PyKdTree(pts)
    print()
    print("Python thread beside a one-thread query (M loop turns/s; alone: sleep):")
    print("sleep       %.3f s %5.1f" % _spin_rate(lambda: time.sleep(0.2)))
    print("small_gicp  %.3f s %5.1f" % _spin_rate(lambda: [sg.batch_knn_search(pts, 32, num_threads=1) for _ in range(4)]))
    print("pykdtree    %.3f s %5.1f" % _spin_rate(lambda: [pk.knn(pts, 32, 1) for _ in range(4)]))


if __name__ == "__main__":
    main()
