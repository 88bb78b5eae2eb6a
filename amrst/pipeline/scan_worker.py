"""The source scan's per-scan stages in a second process kept for the next pair (Linux).

Two threads of one process analyse the two scans of a pair at once
(:func:`amrst.pipeline.analysis.both_scans`), but most of that work is numpy steps
of a few milliseconds and small_gicp queries that hold the GIL: the threads were
only 1.1x faster than one after the other. A second process analysing the source
while this one analyses the target, each on one core with one OpenMP thread, took
0.80-0.86x the threads' time for the per-scan stages and 0.91x for the whole
registration (median per case, 30 shared cases, ``docs/bench/final11``).

The worker is forked at the second pair a process registers and kept: a child
forked for every pair gained nothing (0.97-1.03x), because after a fork both
processes copy each heap page they write (copy-on-write) and numpy's temporaries
reuse the heap; a kept worker has copied its pages once. For the same reason a
one-shot ``amrst register`` keeps the threads (with the worker it took 1.02x). The source goes to it through a pipe (1.2 MB for 50,000
points; scans over :data:`MAX_POINTS` stay with the threads), its analysis comes
back without the neighbour table (only the per-scan stages use it) and without the
cloud (this process has it), and its progress as it goes. Cancel, an error here or
Ctrl-C kill the worker (the next pair forks a new one); a worker that dies makes
this pair's source analysed here. Results are the threads' bit for bit (tested).

Used where a fork is safe: on Linux, with ``analysis.SCAN_THREADS`` at 2, the
calling thread the only Python thread when the worker is forked (a fork copies
only the calling thread; locks other threads held would stay locked), and
``AMRST_SCAN_PROCESS`` not ``0``. The worker uses one OpenMP thread: libgomp's
thread pool does not survive a fork (in the child of a process that had used
OpenMP, a second OpenMP thread hung, tried here).
"""

from __future__ import annotations

import atexit
import contextlib
import logging
import os
import pickle
import select
import signal
import struct
import sys
import threading
import warnings
from dataclasses import replace
from typing import TYPE_CHECKING, Any

from amrst.neighbours import set_threads, threads_here
from amrst.pipeline.analysis import SCAN_THREADS, ScanAnalysis, analyse_scan
from amrst.progress import SharedReporter

if TYPE_CHECKING:
    import numpy as np

    from amrst.params import RegistrationParams
    from amrst.progress import Reporter
    from amrst.types import Cloud

log = logging.getLogger(__name__)

MAX_POINTS = 1_000_000  # larger sources stay with the threads (copying them costs)
_HEAD = struct.Struct("<Q")  # every message: its length, then a pickle
_POLL_S = 0.05  # how often Cancel is checked while waiting for the worker


def usable(source: Cloud) -> bool:
    """Whether the source of this pair goes to the worker process."""
    return (
        sys.platform.startswith("linux")
        and os.environ.get("AMRST_SCAN_PROCESS", "1") != "0"
        and SCAN_THREADS.get() >= 2
        and len(source.xyz) <= MAX_POINTS
    )


def analyse_source_apart(
    target: Cloud,
    source: Cloud,
    params: RegistrationParams,
    stems: tuple[np.ndarray | None, np.ndarray | None],
    reporter: Reporter,
) -> tuple[ScanAnalysis, ScanAnalysis] | None:
    """Analyse the target here and the source in the worker; None when not possible.

    ``stems``: each scan's stem (local frame) or None. Raises what the analyses
    raise, the target's error first (as ``both_scans``).
    """
    global _PAIRS
    _PAIRS += 1
    if _PAIRS < 2 or not usable(source) or not _LOCK.acquire(blocking=False):
        return None
    try:
        worker = _worker()
        if worker is None:
            return None
        shared = SharedReporter(reporter, 2)
        request = (
            (source.xyz, source.offset, dict(source.attributes), source.name),
            params,
            stems[1],
        )
        try:
            worker.send(request)
        except OSError:  # it died since the last pair: the threads, a new one next time
            log.warning("The scan worker process had ended; a new one comes next time.")
            _stop(kill=True)
            return None
        try:
            with threads_here(1):
                tgt = analyse_scan(target, params, shared.task(0, "target"), stems[0])
            answer = worker.receive(shared)
        except BaseException:
            _stop(kill=True)
            raise
        if answer is None:
            log.warning("The scan worker process ended; analysing the source here.")
            _stop(kill=True)
            rep = shared.task(1, "source")
            return tgt, analyse_scan(source, params, rep, stems[1])
        kind, value = answer
        if kind == "error":
            raise value
        return tgt, replace(value, cloud=source)
    finally:
        _LOCK.release()


class _Worker:
    """The forked process and the two pipes to it."""

    def __init__(self) -> None:
        req_r, req_w = os.pipe()
        ans_r, ans_w = os.pipe()
        with warnings.catch_warnings():  # 3.12+: "fork() may lead to deadlocks"
            warnings.simplefilter("ignore", DeprecationWarning)
            pid = os.fork()
        if pid == 0:
            # Only the two pipes and the standard streams: a file lock (flock) or a
            # socket of the parent must not live on in the worker.
            lo, hi = sorted((req_r, ans_w))
            for a, b in ((3, lo), (lo + 1, hi), (hi + 1, os.sysconf("SC_OPEN_MAX"))):
                os.closerange(a, b)
            _serve(req_r, ans_w)  # never returns
        os.close(req_r)
        os.close(ans_w)
        self.pid, self._req, self._ans = pid, os.fdopen(req_w, "wb"), ans_r

    def send(self, request: object) -> None:
        data = pickle.dumps(request, protocol=pickle.HIGHEST_PROTOCOL)
        self._req.write(_HEAD.pack(len(data)) + data)
        self._req.flush()

    def receive(self, shared: SharedReporter) -> tuple[str, Any] | None:
        """Return the worker's answer (its progress relayed meanwhile); None if it died."""
        source = shared.task(1, "source")
        buf = bytearray()
        while True:
            shared.check_cancelled()
            if not select.select([self._ans], [], [], _POLL_S)[0]:
                continue
            chunk = os.read(self._ans, 1 << 20)
            if not chunk:
                return None
            buf += chunk
            while len(buf) >= _HEAD.size:
                (n,) = _HEAD.unpack_from(buf)
                if len(buf) < _HEAD.size + n:
                    break
                kind, value = pickle.loads(buf[_HEAD.size : _HEAD.size + n])
                del buf[: _HEAD.size + n]
                if kind != "progress":
                    return kind, value
                source.progress(*value)

    def close(self, kill: bool) -> None:
        if kill:
            with contextlib.suppress(ProcessLookupError):
                os.kill(self.pid, signal.SIGKILL)
        for close in (self._req.close, lambda: os.close(self._ans)):
            with contextlib.suppress(OSError):  # killed while it read: a broken pipe
                close()
        with contextlib.suppress(ChildProcessError):
            os.waitpid(self.pid, 0)  # a kept worker ends at the end of its input


_LOCK = threading.Lock()  # one pair at a time in the worker
# Pairs this process has registered: the worker serves from the second on (a
# one-shot command was 1.02x slower with it: the fork's copy-on-write cost).
_PAIRS = 0
_WORKER: _Worker | None = None


def _worker() -> _Worker | None:
    global _WORKER
    if _WORKER is None and threading.active_count() == 1:
        _WORKER = _Worker()
        log.info("Source scans go to a worker process (pid %d).", _WORKER.pid)
    return _WORKER


def _stop(kill: bool = False) -> None:
    global _WORKER
    if _WORKER is not None:
        worker, _WORKER = _WORKER, None
        worker.close(kill)


atexit.register(_stop)


def _serve(requests: int, answers: int) -> None:
    """Serve one source scan per request until the input ends (the worker's loop)."""
    code = 1
    try:
        signal.signal(signal.SIGINT, signal.SIG_IGN)  # Ctrl-C: the parent kills it
        set_threads(1)  # the parent's OpenMP threads are not here
        reader = os.fdopen(requests, "rb")
        while True:
            head = reader.read(_HEAD.size)
            if len(head) < _HEAD.size:
                code = 0
                break
            parts, params, stem = pickle.loads(reader.read(_HEAD.unpack(head)[0]))
            _answer(answers, parts, params, stem)
    finally:
        os._exit(code)  # no atexit handlers, no flushing of the parent's buffers


def _answer(
    fd: int, parts: tuple[Any, ...], params: RegistrationParams, stem: Any
) -> None:
    from amrst.types import Cloud

    try:
        an = analyse_scan(Cloud(*parts), params, _PipeReporter(fd), stem)
        pre = replace(an.pre, neighbours=None)
        scene_pre = an.scene_pre and replace(an.scene_pre, neighbours=None)
        message: tuple[str, object] = (
            "result",
            # In transit only: the parent puts its own cloud back.
            replace(an, pre=pre, scene_pre=scene_pre, cloud=None),  # type: ignore[arg-type]
        )
        data = pickle.dumps(message, protocol=pickle.HIGHEST_PROTOCOL)
    except Exception as exc:  # raised in the parent
        try:
            data = pickle.dumps(("error", exc))
        except Exception:  # an error that does not pickle
            data = pickle.dumps(("error", RuntimeError(f"source scan: {exc!r}")))
    os.set_blocking(fd, True)
    os.write(fd, _HEAD.pack(len(data)))
    view = memoryview(data)
    while view:
        view = view[os.write(fd, view) :]


class _PipeReporter:
    """The worker's reporter: progress goes to the parent; Cancel is a kill."""

    def __init__(self, fd: int) -> None:
        self._fd = fd
        os.set_blocking(fd, False)

    def progress(self, fraction: float, message: str = "") -> None:
        data = pickle.dumps(("progress", (float(fraction), str(message)[:200])))
        # Under PIPE_BUF: written whole or not at all (a full pipe drops it).
        with contextlib.suppress(BlockingIOError):
            os.write(self._fd, _HEAD.pack(len(data)) + data)

    def check_cancelled(self) -> None:
        pass
