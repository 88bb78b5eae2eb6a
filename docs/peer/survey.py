"""Run ``amrst info`` on every point-cloud file of the laspy and PDAL test corpora.

Usage::

    python docs/peer/survey.py [ROOT ...] [--jobs 2] [--json OUT] [--all]

ROOT defaults to ``/work/peer/laspy`` and ``/work/peer/pdal`` (extract them from the
repositories laspy/laspy ``tests/data`` and PDAL/PDAL ``test/data``). Each file runs
in its own ``amrst info`` process (60 s limit). The expected point count comes from
the file's own header (LAS/LAZ through laspy, PLY's vertex element, PCD's POINTS),
so "ok" means amrst read as many points as the writer announced. ``--all`` also runs
the files whose extension amrst does not read (they must be refused with exit 2).
"""

from __future__ import annotations

import argparse
import concurrent.futures
import json
import os
import re
import subprocess
import sys
from pathlib import Path

_EXTS = (".las", ".laz", ".ply", ".pcd", ".xyz", ".txt", ".asc", ".csv", ".pts")
_TIMEOUT_S = 60
_MEMORY_LIMIT = 6 << 30  # bytes of address space per child: a runaway read fails
_DEFAULT_ROOTS = ("/work/peer/laspy", "/work/peer/pdal")


def expected_count(path: Path) -> int | None:
    """The point count the file's header announces, or None when unknown."""
    suffix = path.suffix.lower()
    try:
        if suffix in (".las", ".laz"):
            import laspy

            with laspy.open(path) as f:
                return int(f.header.point_count)
        if suffix == ".ply":
            with open(path, "rb") as f:
                for raw in f:
                    words = raw.split()
                    if words[:2] == [b"element", b"vertex"]:
                        return int(words[2])
                    if words[:1] == [b"end_header"]:
                        return None
        if suffix == ".pcd":
            with open(path, "rb") as f:
                for raw in f:
                    words = raw.split()
                    if words[:1] and words[0].upper() == b"POINTS":
                        return int(words[1])
                    if words[:1] and words[0].upper() == b"DATA":
                        return None
    except Exception:  # laspy cannot read it: no expectation
        return None
    return None


def _limit_memory() -> None:
    import resource

    resource.setrlimit(resource.RLIMIT_AS, (_MEMORY_LIMIT, _MEMORY_LIMIT))


def _expected_in_child(path: Path) -> int | None:
    """:func:`expected_count` in a child process: laspy trusts corrupt headers."""
    cmd = [sys.executable, __file__, "--expect", str(path)]
    try:
        proc = subprocess.run(
            cmd, capture_output=True, text=True, timeout=30, preexec_fn=_limit_memory
        )
    except subprocess.TimeoutExpired:
        return None
    out = proc.stdout.strip()
    return int(out) if out.isdigit() else None


def run_one(path: Path) -> dict[str, object]:
    """Run ``amrst info path`` and classify what happened."""
    cmd = [sys.executable, "-m", "amrst.cli", "info", str(path)]
    try:
        proc = subprocess.run(
            cmd,
            capture_output=True,
            text=True,
            timeout=_TIMEOUT_S,
            preexec_fn=_limit_memory,
        )
    except subprocess.TimeoutExpired:
        return {
            "file": str(path),
            "exit": None,
            "points": None,
            "stderr": ["timeout"],
            "expected": _expected_in_child(path),
        }
    match = re.search(r"points\s+([\d,]+)", proc.stdout)
    points = int(match.group(1).replace(",", "")) if match else None
    lines = [line for line in proc.stderr.splitlines() if line.strip()]
    return {
        "file": str(path),
        "exit": proc.returncode,
        "points": points,
        "stderr": lines,
        "expected": _expected_in_child(path),
    }


def verdict(row: dict[str, object]) -> str:
    """ok / warned / count-differs / refused / EXIT-1 / TRACEBACK / TIMEOUT / noisy."""
    lines = row["stderr"]
    assert isinstance(lines, list)
    if lines == ["timeout"]:
        return "TIMEOUT"
    if any("Traceback" in line for line in lines):
        return "TRACEBACK"
    if row["exit"] not in (0, 2):
        return f"EXIT-{row['exit']}"
    if row["exit"] == 2:
        return "refused" if len(lines) == 1 else "refused-noisy"
    exp = row.get("expected")
    if exp is not None and row["points"] != exp:
        return "count-differs"
    return "warned" if lines else "ok"


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("roots", nargs="*", default=list(_DEFAULT_ROOTS))
    p.add_argument("--jobs", type=int, default=2)
    p.add_argument("--json", metavar="OUT", help="write the rows as JSON")
    p.add_argument("--all", action="store_true", help="every file, any extension")
    p.add_argument("--expect", metavar="FILE", help=argparse.SUPPRESS)
    args = p.parse_args(argv)
    if args.expect:
        print(expected_count(Path(args.expect)))
        return 0
    files = sorted(
        f
        for root in args.roots
        for f in Path(root).rglob("*")
        if f.is_file() and (args.all or f.suffix.lower() in _EXTS)
    )
    with concurrent.futures.ThreadPoolExecutor(args.jobs) as pool:
        rows = list(pool.map(run_one, files))
    for row in rows:
        row["verdict"] = verdict(row)
    common = os.path.commonpath([str(Path(r).parent) for r in args.roots] or ["/"])
    width = max((len(os.path.relpath(str(r["file"]), common)) for r in rows), default=4)
    print(f"{'file':<{width}}  {'verdict':<13} {'expected':>9} {'read':>9}  message")
    for row in rows:
        lines = row["stderr"]
        assert isinstance(lines, list)
        message = (lines[-1] if lines else "")[:110]
        exp = "" if row["expected"] is None else row["expected"]
        pts = "" if row["points"] is None else row["points"]
        name = os.path.relpath(str(row["file"]), common)
        print(f"{name:<{width}}  {row['verdict']:<13} {exp:>9} {pts:>9}  {message}")
    counts: dict[str, int] = {}
    for row in rows:
        counts[str(row["verdict"])] = counts.get(str(row["verdict"]), 0) + 1
    print("\nsummary: " + ", ".join(f"{k} {v}" for k, v in sorted(counts.items())))
    if args.json:
        Path(args.json).write_text(json.dumps(rows, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
