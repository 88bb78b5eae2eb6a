"""How far the tree measurements move when they run on a bounded sample.

Usage::

    python docs/bench/scale/measure_sample_check.py CASES_DIR [CASES_DIR ...] [--max-points N]

For every case, under its true transform, measures the target, the moved source and
the merged tree on the whole scans and on seeded samples of at most N points per scan
(``amrst.sampling.measure_pair``), and prints the differences. The default N is the
pipeline's own bound (``MEASURE_MAX_POINTS``), which leaves every shared case whole;
``--max-points 0`` takes a third of the smaller scan, to see what sampling a sparse
scan would cost.
"""

from __future__ import annotations

import argparse
import math

from amrst.io.cases import find_cases, read_case
from amrst.measure import measure_registration
from amrst.sampling import MEASURE_MAX_POINTS, measure_pair


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("cases", nargs="+")
    ap.add_argument("--max-points", type=int, default=MEASURE_MAX_POINTS)
    args = ap.parse_args()
    worst = {"height_cm": 0.0, "dbh_cm": 0.0, "area_pct": 0.0, "width_cm": 0.0}
    print(
        "case | part | n full / sample | d height cm | d DBH cm | d crown area % | d crown width cm"
    )
    for root in args.cases:
        for path in find_cases(root):
            case = read_case(path)
            n = args.max_points or max(
                1000, min(len(case.target), len(case.source)) // 3
            )
            full = measure_registration(case.target, case.source, case.T_target_source)
            part = measure_pair(
                case.target, case.source, case.T_target_source, max_points=n
            )
            for key in ("target", "source", "merged"):
                a, b = full[key], part[key]
                d = {
                    "height_cm": 100 * abs(a.height_m - b.height_m),
                    "dbh_cm": 100 * abs(a.dbh_m - b.dbh_m),
                    "area_pct": 100
                    * abs(a.crown_area_m2 - b.crown_area_m2)
                    / max(a.crown_area_m2, 1e-9),
                    "width_cm": 100 * abs(a.crown_width_m - b.crown_width_m),
                }
                for k, v in d.items():
                    if math.isfinite(v):
                        worst[k] = max(worst[k], v)
                dbh = (
                    "nan->nan"
                    if math.isnan(a.dbh_m) and math.isnan(b.dbh_m)
                    else f"{d['dbh_cm']:.2f}"
                )
                print(
                    f"{path.name} | {key} | {a.n_points} / {b.n_points} | {d['height_cm']:.2f} | "
                    f"{dbh} | {d['area_pct']:.2f} | {d['width_cm']:.2f}"
                )
    print("worst:", {k: round(v, 2) for k, v in worst.items()})


if __name__ == "__main__":
    main()
