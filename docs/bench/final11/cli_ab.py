"""Whole one-shot ``amrst register`` commands, worker against threads (interpreter start included).

Each of the 30 shared cases 3 times per setting (``AMRST_SCAN_PROCESS`` 0 and 1),
alternated, the minimum counting. Measured when the worker was forked at a process's
first pair (``674666c``): 1.019x per case, which is why it is forked at the second
now (a one-shot command no longer uses it).

Run from the repository root: .venv/bin/python docs/bench/final11/cli_ab.py
"""

from __future__ import annotations

import glob
import os
import subprocess
import tempfile
import time

import numpy as np


def main() -> None:
    cases = sorted(glob.glob("../shared/data/cases/*/"))
    cases += sorted(glob.glob("../shared/data/cases_field/*/"))
    best: dict[str, list[float]] = {"0": [], "1": []}
    out = tempfile.mkdtemp()
    for case in cases:
        name = os.path.basename(case.rstrip("/"))
        runs: dict[str, list[float]] = {"0": [], "1": []}
        for i in range(3):
            for m in ("0", "1") if i % 2 == 0 else ("1", "0"):
                cmd = [".venv/bin/amrst", "register", case + "target.ply"]
                cmd += [case + "source.ply", "--out", os.path.join(out, m + name)]
                t0 = time.perf_counter()
                done = subprocess.run(
                    [*cmd, "--quiet"],
                    env={**os.environ, "AMRST_SCAN_PROCESS": m},
                    capture_output=True,
                )
                runs[m].append(time.perf_counter() - t0)
                assert done.returncode in (0, 3), done.stderr[-500:]
        for m in runs:
            best[m].append(min(runs[m]))
        print(name[:30], {m: round(min(v), 3) for m, v in runs.items()}, flush=True)
    a, b = np.array(best["0"]), np.array(best["1"])
    print(
        f"whole command median: threads {np.median(a):.3f} s, worker {np.median(b):.3f} s;"
        f" per case worker/threads median {np.median(b / a):.3f}"
    )


if __name__ == "__main__":
    main()
