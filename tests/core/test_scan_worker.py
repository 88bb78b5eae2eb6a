"""The source scan analysed in a kept worker process (``amrst.pipeline.scan_worker``).

Run in a fresh interpreter: the worker is forked only from a process whose one
Python thread is the caller, and it is a snapshot of that process.
"""

from __future__ import annotations

import pickle
import sys

import numpy as np
import pytest

from tests.conftest import SAMPLE_DIR, run_json_script

pytestmark = pytest.mark.skipif(
    not sys.platform.startswith("linux"), reason="the worker is forked on Linux only"
)

SCRIPT = r"""
import json, os, signal, sys, time
import numpy as np
from amrst import io
from amrst.errors import Cancelled, InvalidInput
from amrst.pipeline import register
from amrst.pipeline import scan_worker
from amrst.progress import EventReporter
from amrst.types import Cloud

tgt, src = (io.read(os.path.join(sys.argv[1], n)) for n in ("target.ply", "source.ply"))
out = {}

# Made before the worker is forked (it is a snapshot): an error class that does not
# rebuild from its pickle, and a log record from the source's analysis.
import logging
from amrst.pipeline import analysis

class StageError(InvalidInput):
    def __init__(self, scan, n):
        super().__init__(f"{scan}: {n} points")

real = analysis.analyse_scan
def analyse_scan(cloud, *args, **kw):
    if cloud.name == "bad.ply":
        raise StageError(cloud.name, len(cloud.xyz))
    if cloud.name == "logme.ply":
        logging.getLogger("amrst.test").warning("hello from %s", cloud.name)
    return real(cloud, *args, **kw)
analysis.analyse_scan = analyse_scan
records = []
class Keep(logging.Handler):
    def emit(self, record):
        records.append(record.getMessage())
logging.getLogger("amrst.test").addHandler(Keep())

def pid():
    return None if scan_worker._WORKER is None else scan_worker._WORKER.pid

def alive(p):
    try:
        os.kill(p, 0)
        return True
    except ProcessLookupError:
        return False

def same(a, b):
    return bool(
        np.array_equal(a.T_target_source, b.T_target_source)
        and np.array_equal(a.source.xyz, b.source.xyz)
        and np.array_equal(a.source.is_wood, b.source.is_wood)
        and np.array_equal(a.source.keypoints.xyz, b.source.keypoints.xyz)
        and np.array_equal(a.target.keypoints.xyz, b.target.keypoints.xyz)
    )

os.environ["AMRST_SCAN_PROCESS"] = "1"
one_shot = register(tgt, src)  # a process's first pair: the threads
out["worker_at_first_pair"] = pid()
os.environ["AMRST_SCAN_PROCESS"] = "0"
threads = register(tgt, src)
out["worker_when_off"] = pid()
out["one_shot_same"] = same(one_shot, threads)
os.environ["AMRST_SCAN_PROCESS"] = "1"
messages = []
first = register(tgt, src, reporter=EventReporter(lambda f, m: messages.append(m)))
out["first_pid"] = pid()
out["same_as_threads"] = same(first, threads)
out["source_progress"] = sum(m.startswith("source:") for m in messages)
out["source_cloud_kept"] = first.source.cloud is src
second = register(tgt, src)
out["second_pid"] = pid()
out["second_same"] = same(second, threads)

# Cancel while this process waits for the worker (a small target, the whole source).
small = Cloud(tgt.xyz[::8].copy(), tgt.offset, name="small target")
rep = EventReporter(lambda f, m: rep.cancel() if m.startswith("source:") else None)
old = pid()
t0 = time.perf_counter()
try:
    register(small, src, reporter=rep)
    out["cancel"] = "finished"
except Cancelled:
    out["cancel"] = "cancelled"
out["cancel_s"] = time.perf_counter() - t0
out["after_cancel_pid"] = pid()
out["old_worker_alive"] = alive(old)

# A source the analysis refuses: its error, and the worker stays.
register(tgt, src)
kept = pid()
few = Cloud(src.xyz[:50].copy(), src.offset, name="few.ply")
try:
    register(tgt, few)
    out["few"] = "no error"
except InvalidInput as exc:
    out["few"] = str(exc)
out["worker_kept_after_error"] = pid() == kept

# The worker killed from outside: the next pair still registers, a new worker after.
os.kill(kept, signal.SIGKILL)
time.sleep(0.2)
after_kill = register(tgt, src)
out["after_kill_same"] = same(after_kill, threads)
again = register(tgt, src)
out["new_worker"] = pid() not in (None, kept)
out["again_same"] = same(again, threads)
bad = Cloud(src.xyz, src.offset, name="bad.ply")
try:
    register(tgt, bad)
except InvalidInput as exc:
    out["bad"] = [type(exc).__name__, str(exc) == f"bad.ply: {len(src.xyz)} points"]
out["worker_kept_after_bad"] = pid() is not None
records.clear()
register(tgt, Cloud(src.xyz, src.offset, name="logme.ply"))
out["records"] = list(records)
out["logged_by_worker"] = pid() is not None

# A process forked from this one forgets this one's worker; this one keeps it.
child = os.fork()
if child == 0:
    os._exit(0 if scan_worker._WORKER is None and scan_worker._PAIRS == 0 else 1)
out["child_forgot"] = os.waitpid(child, 0)[1] == 0
out["still_same"] = same(register(tgt, src), threads)
print(json.dumps(out))
"""


def test_the_worker_gives_the_threads_results_and_recovers():
    out = run_json_script(SCRIPT, str(SAMPLE_DIR))
    assert out["worker_when_off"] is None
    assert out["worker_at_first_pair"] is None
    assert out["one_shot_same"]
    assert out["first_pid"] is not None
    assert out["same_as_threads"]
    assert out["second_same"]
    assert out["second_pid"] == out["first_pid"]  # kept for the next pair
    assert out["source_progress"] > 0  # its progress reaches the caller
    assert out["source_cloud_kept"]
    assert out["cancel"] == "cancelled"
    assert out["cancel_s"] < 5
    assert out["after_cancel_pid"] is None
    assert not out["old_worker_alive"]
    assert out["few"].startswith("few.ply: Only")
    assert out["worker_kept_after_error"]
    assert out["after_kill_same"]
    assert out["again_same"]
    assert out["new_worker"]
    # An error class that does not rebuild arrives as its nearest class that does.
    assert out["bad"] == ["InvalidInput", True]
    assert out["worker_kept_after_bad"]
    assert out["records"] == ["hello from logme.ply"]  # the worker's log, here
    assert out["logged_by_worker"]
    assert out["child_forgot"]
    assert out["still_same"]


def test_a_cloud_pickles_whole_and_frozen():
    """The worker (and the app's engine process) receive clouds as pickles."""
    from amrst.types import Cloud

    rng = np.random.default_rng(3)
    cloud = Cloud(
        rng.random((50, 3)),
        [500000.0, 5000000.0, 12.0],
        {"intensity": rng.random(50), "classification": np.arange(50, dtype=np.uint8)},
        "a.las",
        {"point_format": 3},
    )
    back = pickle.loads(pickle.dumps(cloud, protocol=pickle.HIGHEST_PROTOCOL))
    assert back.name == "a.las"
    assert dict(back.meta) == {"point_format": 3}
    assert np.array_equal(back.xyz, cloud.xyz)
    assert np.array_equal(back.offset, cloud.offset)
    assert set(back.attributes) == {"intensity", "classification"}
    for key, value in cloud.attributes.items():
        assert np.array_equal(back.attributes[key], value)
        assert back.attributes[key].dtype == value.dtype
    assert not back.xyz.flags.writeable  # checked and frozen again
    with pytest.raises(TypeError):
        back.attributes["intensity"] = None  # type: ignore[index]
