"""Per-kernel speed of each swap, old against new, interleaved in one process.

Usage::

    python docs/bench/scale/kernels.py [CASE_DIR] [--repeat 7]

CASE_DIR defaults to ``../shared/data/cases/08_treels-pine-normal``. Each kernel runs
the way the pipeline calls it, on that case's geometry (the source moved by the
truth, as ICP sees it near convergence); every pair of old/new calls alternates and
the best of ``--repeat`` is kept, so both see the same machine load. Prints Markdown.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np
from scipy.spatial import cKDTree

from amrst.bench.scale import densify
from amrst.io.cases import read_case
from amrst.neighbours import NearestTree, knn
from amrst.stages.voxels import voxel_grid, voxel_representatives


def _old_voxel_representatives(xyz: np.ndarray, voxel: float) -> np.ndarray:
    """The stable-sort version (before issue 15), representatives only."""
    code = voxel_grid(xyz, voxel)[1]
    order = np.argsort(code, kind="stable")
    sc = code[order]
    new = np.r_[True, sc[1:] != sc[:-1]]
    group = np.cumsum(new) - 1
    n = int(group[-1]) + 1
    pts = xyz[order]
    counts = np.bincount(group, minlength=n)
    cen = np.column_stack([np.bincount(group, pts[:, d], n) for d in range(3)])
    dist = np.sum((pts - cen[group] / counts[group, None]) ** 2, axis=1)
    nearest = np.minimum.reduceat(dist, np.flatnonzero(new))
    hit = np.flatnonzero(dist == nearest[group])
    first = np.r_[True, group[hit][1:] != group[hit][:-1]]
    return np.sort(order[hit[first]])


def _best(fns: dict, repeat: int) -> dict:
    best = dict.fromkeys(fns, np.inf)
    for _ in range(repeat):
        for k, f in fns.items():
            t0 = time.perf_counter()
            f()
            best[k] = min(best[k], time.perf_counter() - t0)
    return best


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument(
        "case", nargs="?", default="../shared/data/cases/08_treels-pine-normal"
    )
    ap.add_argument("--repeat", type=int, default=7)
    args = ap.parse_args()
    case = read_case(args.case)
    T = np.asarray(
        json.loads((Path(args.case) / "truth.json").read_text())["T_target_source"]
    )
    tgt = case.target.xyz
    src = (
        case.source.xyz @ T[:3, :3].T
        + T[:3, 3]
        + (case.source.offset - case.target.offset)
    )
    dense = densify(case.target, 2_000_000, 0.003, 0).xyz
    rng = np.random.default_rng(0)
    fit = src[rng.choice(len(src), 5000, replace=False)]
    rows = []

    def add(name: str, old, new, repeat: int = args.repeat) -> None:
        b = _best({"old": old, "new": new}, repeat)
        rows.append((name, b["old"], b["new"]))

    for k, what in (
        (13, "outlier filter"),
        (30, "wood features"),
        (17, "skeleton graph"),
    ):
        add(
            f"kNN self-query k={k} ({what}), {len(tgt):,} pts",
            lambda k=k: cKDTree(tgt).query(tgt, k=k, workers=-1),
            lambda k=k: knn(tgt, k),
        )
    ct, nt = cKDTree(tgt), NearestTree(tgt)
    add(
        "ICP correspondences: 5,000 pts, k=2, bound 0.225 m (tree reused)",
        lambda: ct.query(fit, k=2, distance_upper_bound=0.225),
        lambda: nt.query(fit, k=2, distance_upper_bound=0.225),
        args.repeat * 5,
    )
    add(
        f"cloud metrics: NN of {len(src):,} pts both ways (trees built)",
        lambda: (
            cKDTree(tgt).query(src, workers=-1),
            cKDTree(src).query(tgt, workers=-1),
        ),
        lambda: (NearestTree(tgt).query(src), NearestTree(src).query(tgt)),
    )
    add(
        "voxel representatives, 2,000,000 pts, 3 cm",
        lambda: _old_voxel_representatives(dense, 0.03),
        lambda: voxel_representatives(dense, 0.03),
        3,
    )
    print("| kernel | scipy / before (s) | now (s) | speed-up |")
    print("|---|---|---|---|")
    for name, old, new in rows:
        print(f"| {name} | {old:.4f} | {new:.4f} | {old / new:.2f}x |")


if __name__ == "__main__":
    main()
