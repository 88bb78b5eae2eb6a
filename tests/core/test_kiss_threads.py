"""KISS-Matcher runs on one thread: the same pose on every run.

With its TBB and OpenMP threads its pose can vary from run to run, so a campaign
tree would not be bit for bit the ``amrst register`` result. The check runs in a
fresh process: TBB starts its worker threads at its first parallel loop there.
"""

from __future__ import annotations

import os
from pathlib import Path

import pytest

SCRIPT = r"""
import ctypes, json, os, sys
import numpy as np
from amrst import io
from amrst.types import apply_transform, make_transform
from amrst.stages import kiss_threads
from amrst.stages.global_match import kiss_global
from amrst.stages.kiss_threads import kiss_one_thread

# tbb::detail::r1::global_control_active_value
ACTIVE = "_ZN3tbb6detail2r127global_control_active_valueEi"

def kiss_tbb_threads():
    # The TBB thread limit in force for kiss_matcher (None: not known).
    lib = kiss_threads._tbb()
    active = None if lib is None else getattr(lib, ACTIVE, None)
    if active is None:
        return None
    active.restype = ctypes.c_size_t
    return int(active(kiss_threads._MAX_ALLOWED_PARALLELISM))

xyz = io.read(sys.argv[1]).xyz
c, s = np.cos(np.radians(120)), np.sin(np.radians(120))
T = make_transform(np.array([[c, -s, 0], [s, c, 0], [0, 0, 1.0]]), [2.0, -1.0, 0.3])
source = apply_transform(T, xyz)[::2]
before = len(os.listdir("/proc/self/task"))
default = kiss_tbb_threads()
with kiss_one_thread():  # kiss_global holds the limit itself; this keeps it for the count
    inside = kiss_tbb_threads()
    runs = [kiss_global(xyz, source, 0.1) for _ in range(3)]
    during = len(os.listdir("/proc/self/task"))
print(json.dumps({
    "threads_before": before,
    "threads_after": during,
    "tbb_limit": inside,
    "tbb_default": default,
    "tbb_after": kiss_tbb_threads(),
    "poses": [r[0].tolist() for r in runs],
    "inliers": [r[1] for r in runs],
}))
"""


@pytest.mark.skipif(not Path("/proc/self/task").is_dir(), reason="Linux /proc")
def test_kiss_matcher_starts_no_thread_and_repeats_its_pose(
    json_script, tiny_tree_path
) -> None:
    pytest.importorskip("kiss_matcher")
    env = {k: v for k, v in os.environ.items() if k != "OMP_NUM_THREADS"}
    doc = json_script(SCRIPT, str(tiny_tree_path), env=env, timeout=120)
    assert doc["tbb_limit"] == 1
    # Only inside the block: other KISS-Matcher calls (the bench's peer) keep theirs.
    assert doc["tbb_after"] == doc["tbb_default"]
    # No TBB worker, no OpenMP team: the threads are those the process had before.
    assert doc["threads_after"] == doc["threads_before"], doc
    assert doc["inliers"][0] > 0
    assert all(p == doc["poses"][0] for p in doc["poses"]), doc["inliers"]


def test_the_benchmark_baseline_runs_kiss_matcher_on_its_own_threads(
    monkeypatch, tiny_tree_path
) -> None:
    """The peer is timed as shipped: our one-thread limit must not reach it."""
    pytest.importorskip("kiss_matcher")
    import contextlib

    from amrst import io
    from amrst.baselines.kiss_matcher import KissParams, _global
    from amrst.stages import kiss_threads
    from amrst.stages.global_match import kiss_global

    entered = []

    @contextlib.contextmanager
    def recording():
        entered.append(True)
        yield

    monkeypatch.setattr(kiss_threads, "kiss_one_thread", recording)
    xyz = io.read(tiny_tree_path).xyz
    _global(xyz, xyz[::2] + 0.5, KissParams())
    assert entered == []
    kiss_global(xyz, xyz[::2] + 0.5, 0.1)  # our pipeline's call
    assert entered == [True]
