"""Time and peak memory of ``amrst clip`` against reading the whole file.

Usage::

    python docs/clip/measure.py [--tile N]

Each run is a fresh process (peak memory is its own VmHWM, Linux). Files: the
treeiso Lodgepole-pine plot (1.5M points, about ten pines) and the RIEGL
single-position scan from ../shared/data/trees, and, with ``--tile N``, a plot made
of N shifted copies of the pine plot (written once to /tmp) to show that memory
stays bounded as the file grows. The baseline is ``amrst.io.read`` of the whole
file in the same run.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
from pathlib import Path

DATA = Path(__file__).resolve().parents[2].parent / "shared" / "data" / "trees"
CASES = {
    DATA / "treeiso" / "LPine1_demo.laz": [(-0.14, 2.88), (3.87, 1.38), (11.12, 4.38)],
    DATA / "rtls" / "TLS_scan_single_position.laz": [(2.01, 1.29), (-2.49, 0.29)],
}
RADIUS_M = 1.5

_CHILD = """
import json, sys, time
from amrst import io
path, mode = sys.argv[1], sys.argv[2]
t = time.perf_counter()
if mode == "read":
    n = len(io.read(path))
else:
    x, y, r = map(float, sys.argv[3:6])
    n = len(io.read_region(path, (x, y), r))
dt = time.perf_counter() - t
status = open("/proc/self/status").read().split("VmHWM:")[1]
peak = int(status.split()[0]) / 1024  # kB; unlike ru_maxrss, not inherited
print(json.dumps({"points": n, "seconds": dt, "peak_mb": peak}))
"""


def run(path: Path, mode: str, *args: float) -> dict[str, float]:
    """One measurement in a fresh process."""
    cmd = [sys.executable, "-c", _CHILD, str(path), mode, *map(str, args)]
    out = subprocess.run(cmd, capture_output=True, text=True, check=True).stdout
    return json.loads(out.strip().splitlines()[-1])


def tiled(n: int) -> Path:
    """N copies of the pine plot side by side, written once (LAZ)."""
    from amrst import io
    from amrst.types import Cloud

    out = Path(f"/tmp/amrst-clip-tiled-{n}.laz")
    if out.exists():
        return out
    import numpy as np

    plot = io.read(next(iter(CASES)))
    xyz = np.vstack([plot.xyz + np.array([20.0 * i, 0.0, 0.0]) for i in range(n)])
    attrs = {k: np.concatenate([v] * n) for k, v in plot.attributes.items()}
    io.write(out, Cloud(xyz, plot.offset, attrs, meta=plot.meta))
    return out


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--tile", type=int, default=0)
    p.add_argument(
        "--file",
        nargs=3,
        action="append",
        default=[],
        metavar=("PATH", "X", "Y"),
        help="another file and stem, e.g. a COPC file",
    )
    args = p.parse_args()
    cases = dict(CASES)
    for path, x, y in args.file:
        cases[Path(path)] = [(float(x), float(y))]
    if args.tile:
        cases[tiled(args.tile)] = [(11.12 + 20.0 * (args.tile - 1), 4.38)]
    print(f"{'file':<40} {'what':<22} {'points':>10} {'time s':>7} {'peak MB':>8}")
    for path, stems in cases.items():
        base = run(path, "read")
        print(
            f"{path.name:<40} {'whole file (io.read)':<22} {base['points']:>10,} "
            f"{base['seconds']:>7.2f} {base['peak_mb']:>8.0f}"
        )
        for x, y in stems:
            got = run(path, "clip", x, y, RADIUS_M)
            print(
                f"{'':<40} {f'clip ({x:g}, {y:g}) r {RADIUS_M:g}':<22} "
                f"{got['points']:>10,} {got['seconds']:>7.2f} {got['peak_mb']:>8.0f}"
            )
    return 0


if __name__ == "__main__":
    sys.exit(main())
