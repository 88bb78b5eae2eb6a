"""DBH of the merged registration against the same measurement on the complete tree.

    .venv/bin/python docs/bench/dbh/dbh_check.py [../shared/data] > docs/bench/dbh/results.md

For every case of ``shared/data/cases`` whose tree is in ``shared/data/trees``, the
scans are merged with the TRUE transform (this checks the measurement, not the
registration) and measured with ``amrst.measure``: each scan alone and merged, against
the complete tree cloud measured the same way. Case 18 is left out: its scans are two
dates of a growing tree.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np

from amrst import io
from amrst.measure import measure_registration, measure_tree

TREES = {
    "itsme-tree1": "itsme/tree_1_pc.txt",
    "itsme-tree2": "itsme/tree_2_pc.txt",
    "itsme-buttressed1": "itsme/buttressed_tree_1_pc.txt",
    "archi-tree1": "archi/Tree_1_point_cloud.las",
    "archi-tree2": "archi/Tree_2_point_cloud.las",
    "voxr-t0-normal": "voxr/Tree_t0.asc",
    "voxr-t0-hard": "voxr/Tree_t0.asc",
    "rtls-pctree": "rtls/pc_tree.txt",
    "treels-pine": "treels/pine.laz",
    "treels-spruce": "treels/spruce.laz",
    "palm1": "pytlidar/tree_1.las",
    "woodske-or": "woodske/OR-SIWOOD.csv",
}


def _cm(value: float) -> str:
    return f"{100 * value:.1f}" if np.isfinite(value) else "n/a"


def main(root: Path) -> None:
    ref = {
        k: measure_tree(io.read(root / "trees" / v).world_xyz) for k, v in TREES.items()
    }
    print(
        "| case | complete tree DBH (cm) | merged (cm) | stem arc merged (°) | target alone | source alone |"
    )
    print("|---|---|---|---|---|---|")
    merged_err, single_err, n_single = [], [], 0
    for case in sorted((root / "cases").iterdir()):
        key = next((k for k in TREES if k in case.name), None)
        if key is None or case.name.startswith("18"):
            continue
        truth = json.loads((case / "truth.json").read_text())["T_target_source"]
        m = measure_registration(
            io.read(case / "target.ply"), io.read(case / "source.ply"), np.array(truth)
        )
        r = ref[key].dbh_m
        arc = m["merged"].stem.arc_deg if m["merged"].stem else float("nan")
        print(
            f"| {case.name} | {_cm(r)} | {_cm(m['merged'].dbh_m)} | {arc:.0f} | "
            f"{_cm(m['target'].dbh_m)} | {_cm(m['source'].dbh_m)} |"
        )
        if not np.isfinite(r):
            continue
        if np.isfinite(m["merged"].dbh_m):
            merged_err.append(abs(m["merged"].dbh_m - r) * 100)
        for scan in ("target", "source"):
            n_single += 1
            if np.isfinite(m[scan].dbh_m):
                single_err.append(abs(m[scan].dbh_m - r) * 100)
    for name, err in (("merged", merged_err), ("single scans", single_err)):
        e = np.array(err)
        print(
            f"\n{name}: {len(e)} measured, median |error| {np.median(e):.2f} cm, "
            f"within 1 cm {int(np.sum(e <= 1))}/{len(e)}, largest {e.max():.1f} cm"
        )
    print(f"(single scans without a DBH: {n_single - len(single_err)})")


if __name__ == "__main__":
    main(Path(sys.argv[1] if len(sys.argv) > 1 else "../shared/data"))
