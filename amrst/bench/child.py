"""One ``amrst`` command run in a child process, as a user runs it.

The scale benchmarks time commands this way: the wall time, the child's peak
memory and its stderr lines.
"""

from __future__ import annotations

import io
import os
import subprocess
import sys
import time
from dataclasses import dataclass


@dataclass(frozen=True, slots=True)
class ChildRun:
    """One ``amrst`` command run in a child process, as a user runs it."""

    wall_s: float  # interpreter start included
    peak_mb: float  # the child's maximum resident set size (wait4)
    exit_code: int
    stderr: tuple[tuple[float, str], ...]  # lines, each with seconds since the start


def run_amrst(*args: str) -> ChildRun:
    """Run ``python -m amrst.cli ARGS`` and wait for it; stdout is dropped.

    Its stderr lines are kept, each stamped with the seconds since the start, and
    echoed when the command fails, so a failed row says why.
    """
    cmd = [sys.executable, "-m", "amrst.cli", *args]
    t0 = time.perf_counter()
    proc = subprocess.Popen(
        cmd, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True
    )
    with proc.stderr or io.StringIO() as err:
        lines = tuple((time.perf_counter() - t0, ln.rstrip()) for ln in err)
    _, status, usage = os.wait4(proc.pid, 0)
    wall = time.perf_counter() - t0
    code = proc.returncode = os.waitstatus_to_exitcode(status)
    if code:
        for _, line in lines[-5:]:
            print(line, file=sys.stderr)
    return ChildRun(wall, usage.ru_maxrss / 1024.0, code, lines)
