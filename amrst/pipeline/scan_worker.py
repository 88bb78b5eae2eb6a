"""The source scan's per-scan stages in a second process kept for the next pair (Linux).

Two threads of one process analyse the two scans of a pair at once
(:func:`amrst.pipeline.analysis.both_scans`), but most of that work is numpy steps
of a few milliseconds and small_gicp queries that hold the GIL: the threads were
only 1.1x faster than one after the other. A second process analysing the source
while this one analyses the target, each on one core with one OpenMP thread, took
0.80-0.86x the threads' time for the per-scan stages and 0.87-0.88x for the whole
registration (median per case, 30 shared cases, ``docs/bench/final11``).

The worker is forked at the second pair a process registers and kept: a child
forked for every pair gained nothing (0.97-1.03x), because after a fork both
processes copy each heap page they write (copy-on-write) and numpy's temporaries
reuse the heap; a kept worker has copied its pages once. For the same reason a
one-shot ``amrst register`` keeps the threads (with the worker it took 1.02x).

The source goes to it through a pipe (1.2 MB for 50,000 points; scans over
:data:`MAX_POINTS` stay with the threads). Its analysis comes back without the
neighbour table (megabytes; only the per-scan stages use it, so a second analysis
of the source for the ground rule queries again: one field case in ten) and
without the cloud (this process has it); its progress and log records come as it
goes (``scan_worker_child``). Cancel, an error here or Ctrl-C kill the worker (the
next pair forks a new one); a worker that dies makes this pair's source analysed
here. Results are the threads' bit for bit (tested).

Used where a fork is safe: on Linux, with ``analysis.SCAN_THREADS`` at 2, the
calling thread the only Python thread when the worker is forked (a fork copies
only the calling thread; locks other threads held would stay locked), and
``AMRST_SCAN_PROCESS`` not ``0``. The worker uses one OpenMP thread: libgomp's
thread pool does not survive a fork (in the child of a process that had used
OpenMP, a second OpenMP thread hung, tried here). It keeps every fd closed but its
pipes (no inherited file lock), and a process forked from this one later forgets
this one's worker (``os.register_at_fork``).

The worker is a snapshot of this process at its fork: it keeps what this process
held then (freed here later, still mapped there), and a change made to the
engine's code afterwards (a monkeypatch) does not reach it.
"""

from __future__ import annotations

import atexit
import contextlib
import logging
import os
import pickle
import select
import signal
import sys
import threading
import time
import warnings
from dataclasses import replace
from typing import TYPE_CHECKING, Any

from amrst.neighbours import threads_here
from amrst.pipeline.analysis import SCAN_THREADS, ScanAnalysis, analyse_scan
from amrst.pipeline.scan_worker_child import HEAD, serve, write_all
from amrst.progress import SharedReporter

if TYPE_CHECKING:
    import numpy as np

    from amrst.params import RegistrationParams
    from amrst.progress import Reporter
    from amrst.types import Cloud

log = logging.getLogger(__name__)

MAX_POINTS = 1_000_000  # larger sources stay with the threads (copying them costs)
_POLL_MS = 50  # how often Cancel is checked while waiting for the worker


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
        try:
            # Anything that stops an exchange halfway kills the worker: a request
            # or an answer left in a pipe would be read with the next pair's.
            try:
                seq = worker.send(source, params, stems[1])
            except OSError:  # it had ended: the threads now, a new one next time
                log.warning("The scan worker process had ended; a new one next time.")
                _stop(kill=True)
                return None
            with threads_here(1):
                tgt = analyse_scan(target, params, shared.task(0, "target"), stems[0])
            answer = worker.receive(seq, shared)
        except BaseException:
            _stop(kill=True)
            raise
        if answer is None:
            log.warning("The scan worker process failed; analysing the source here.")
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
        # Ctrl-C between the fork and the worker's own handler would run this
        # process's code in the worker: held back until the worker ignores it.
        mask = signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGINT})
        try:
            with warnings.catch_warnings():  # 3.12+: "fork() may lead to deadlocks"
                warnings.simplefilter("ignore", DeprecationWarning)
                pid = os.fork()
        except OSError:
            signal.pthread_sigmask(signal.SIG_SETMASK, mask)
            for fd in (req_r, req_w, ans_r, ans_w):
                os.close(fd)
            raise
        if pid == 0:
            try:
                # Only the two pipes and the standard streams: a file lock (flock)
                # or a socket of the parent must not live on in the worker.
                lo, hi = sorted((req_r, ans_w))
                for a, b in (
                    (3, lo),
                    (lo + 1, hi),
                    (hi + 1, os.sysconf("SC_OPEN_MAX")),
                ):
                    os.closerange(a, b)
                serve(req_r, ans_w)
            finally:
                os._exit(1)
        signal.pthread_sigmask(signal.SIG_SETMASK, mask)  # the worker: in serve()
        os.close(req_r)
        os.close(ans_w)
        self.pid, self.req, self.ans, self.seq = pid, req_w, ans_r, 0

    def send(self, source: Cloud, params: RegistrationParams, stem: Any) -> int:
        """Send one source scan; return the request's number."""
        self.seq += 1
        data = (self.seq, source, params, stem)
        write_all(self.req, pickle.dumps(data, protocol=pickle.HIGHEST_PROTOCOL))
        return self.seq

    def receive(self, seq: int, shared: SharedReporter) -> tuple[str, Any] | None:
        """Return the answer to request ``seq``; None if the worker died or misspoke.

        Progress and log records are relayed meanwhile.
        """
        source = shared.task(1, "source")
        poll = select.poll()  # select() fails on descriptors over 1023
        poll.register(self.ans, select.POLLIN)
        buf = bytearray()
        while True:
            shared.check_cancelled()
            if not poll.poll(_POLL_MS):
                continue
            chunk = os.read(self.ans, 1 << 20)
            if not chunk:
                return None
            buf += chunk
            while len(buf) >= HEAD.size:
                (n,) = HEAD.unpack_from(buf)
                if len(buf) < HEAD.size + n:
                    break
                try:
                    kind, got, value = pickle.loads(buf[HEAD.size : HEAD.size + n])
                except Exception:  # e.g. an error class that does not rebuild
                    log.exception("An answer of the scan worker could not be read.")
                    return None
                del buf[: HEAD.size + n]
                if got != seq:
                    return None
                if kind == "progress":
                    source.progress(*value)
                elif kind == "log":
                    logging.getLogger(value.name).handle(value)
                else:
                    return kind, value

    def close(self, kill: bool) -> None:
        """End the worker: killed, or told by the end of its input.

        Killed all the same if it has not ended within a second (e.g. stopped).
        """
        if kill:
            with contextlib.suppress(ProcessLookupError):
                os.kill(self.pid, signal.SIGKILL)
        for fd in (self.req, self.ans):
            with contextlib.suppress(OSError):
                os.close(fd)
        with contextlib.suppress(ChildProcessError):
            deadline = time.monotonic() + 1.0
            while not os.waitpid(self.pid, os.WNOHANG)[0]:
                if time.monotonic() > deadline:
                    with contextlib.suppress(ProcessLookupError):
                        os.kill(self.pid, signal.SIGKILL)
                    os.waitpid(self.pid, 0)
                    break
                time.sleep(0.005)


_LOCK = threading.Lock()  # one pair at a time in the worker
# Pairs this process has registered: the worker serves from the second on (a
# one-shot command was 1.02x slower with it: the fork's copy-on-write cost).
_PAIRS = 0
_WORKER: _Worker | None = None
_FORK_FAILED = False


def _worker() -> _Worker | None:
    global _WORKER, _FORK_FAILED
    if _WORKER is None and not _FORK_FAILED and threading.active_count() == 1:
        try:
            _WORKER = _Worker()
        except OSError as exc:  # a process limit, memory: the threads from now on
            _FORK_FAILED = True
            log.warning("No scan worker process (%s); the scans use two threads.", exc)
            return None
        log.info("Source scans go to a worker process (pid %d).", _WORKER.pid)
    return _WORKER


def _stop(kill: bool = False) -> None:
    global _WORKER
    if _WORKER is not None:
        worker, _WORKER = _WORKER, None
        worker.close(kill)


def _forget() -> None:
    """Forget this process's worker in a process forked from it.

    Its pipes closed there, not waited for at exit, and no pair registered yet.
    """
    global _WORKER, _PAIRS, _LOCK
    if _WORKER is not None:
        for fd in (_WORKER.req, _WORKER.ans):
            with contextlib.suppress(OSError):
                os.close(fd)
    _WORKER, _PAIRS, _LOCK = None, 0, threading.Lock()


atexit.register(_stop)
os.register_at_fork(after_in_child=_forget)
