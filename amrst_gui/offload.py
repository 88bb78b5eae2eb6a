"""Long number crunching of the Scans dock in a helper process (issue 15).

Describing a 10M-point scan takes seconds, most of it the median nearest-neighbour
spacing (sorts and k-d trees, slab by slab). In a worker thread every one of those
numpy and scipy calls competes with the GUI thread for the Python GIL, and each of
the many GIL hand-overs a frame needs (Qt and VTK release it on every call) waits
behind it: the window stalled 0.1-0.25 s while a scan was described, whatever the
slab size. A separate process has its own GIL; the operating system shares the
cores between it and the window fairly.

One helper process (``python -m amrst_gui.offload_helper``: a plain interpreter
that imports only numpy and the spacing code, never the app or the caller's main
script, as multiprocessing's spawn would) starts with the first description (the
descriptions wait until the views have drawn a new scan). The points go to it
through shared memory (copied in chunks that release the GIL); the request and the
answer are one line of JSON each over its stdin and stdout. Cancel kills the helper
(a 10M-point spacing would otherwise run on for seconds); the next request starts a
fresh one. If the helper cannot run, the spacing is computed in the calling thread
as before.
"""

from __future__ import annotations

import atexit
import json
import logging
import select
import subprocess
import threading
from typing import TYPE_CHECKING

import numpy as np

from amrst.errors import Cancelled

if TYPE_CHECKING:
    from amrst.progress import Reporter

log = logging.getLogger("amrst_gui.offload")

# Rows copied into shared memory at once: 24 MB of float64, a few milliseconds.
COPY_ROWS = 1_000_000
POLL_S = 0.1  # how often a waiting worker looks at Cancel


class Helper:
    """The helper process; one request at a time (callers queue on a lock)."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._proc: subprocess.Popen[bytes] | None = None

    def start(self) -> None:
        """Start the helper now (its imports take about a second, in the helper)."""
        with self._lock:
            self._ensure()

    def _ensure(self) -> subprocess.Popen[bytes]:
        if self._proc is None or self._proc.poll() is not None:
            from amrst_gui.engine_process import helper_command

            self.stop()  # a helper that died: its pipes
            command, env = helper_command("amrst_gui.offload_helper")
            self._proc = subprocess.Popen(
                command,
                stdin=subprocess.PIPE,
                stdout=subprocess.PIPE,
                env=env,
            )
        return self._proc

    def stop(self) -> None:
        """End the helper without waiting for what it computes."""
        from amrst_gui.engine_process import end_process

        proc, self._proc = self._proc, None
        end_process(proc)

    def median_spacing(self, xyz: np.ndarray, reporter: Reporter) -> float | None:
        """``amrst.io.describe.median_spacing(xyz)`` (N, 3), computed in the helper;
        raises ``Cancelled`` within ``POLL_S`` of a Cancel."""
        from multiprocessing import shared_memory

        from amrst.io.describe import median_spacing as here

        if len(xyz) < 2:
            return here(xyz)
        with self._lock:
            reporter.check_cancelled()
            try:
                proc = self._ensure()
                shm = shared_memory.SharedMemory(create=True, size=xyz.nbytes)
            except Exception as exc:  # no processes or no shared memory here
                log.info("No helper process (%s); spacing computed here", exc)
                return here(xyz)
            try:
                dst: np.ndarray = np.ndarray(xyz.shape, xyz.dtype, buffer=shm.buf)
                for i in range(0, len(xyz), COPY_ROWS):
                    dst[i : i + COPY_ROWS] = xyz[i : i + COPY_ROWS]
                    reporter.check_cancelled()
                del dst  # no view may outlive the mapping
                ask = {"shm": shm.name, "shape": xyz.shape, "dtype": xyz.dtype.str}
                answer = self._ask(proc, ask, reporter)
            finally:
                shm.close()
                shm.unlink()
        if answer is None:  # the helper died or could not answer
            return here(xyz)
        return answer.get("spacing")

    def _ask(self, proc, request: dict, reporter: Reporter) -> dict | None:
        assert proc.stdin is not None
        assert proc.stdout is not None
        try:
            proc.stdin.write((json.dumps(request) + "\n").encode())
            proc.stdin.flush()
            while not select.select([proc.stdout], [], [], POLL_S)[0]:
                try:
                    reporter.check_cancelled()
                except Cancelled:
                    self.stop()  # it would compute on for seconds; the next
                    raise  # request starts a fresh one
            line = proc.stdout.readline()
        except OSError as exc:  # a broken pipe: the helper is gone
            log.info("Helper process failed (%s); spacing computed here", exc)
            self.stop()
            return None
        if not line:  # the helper died (or the window closed and ended it)
            self.stop()
            reporter.check_cancelled()
            return None
        answer = json.loads(line)
        if "error" in answer:
            log.info("Helper process: %s; spacing computed here", answer["error"])
            return None
        return answer


HELPER = Helper()
atexit.register(HELPER.stop)


def start() -> None:
    """Start the helper process (never raises: without it, work stays here)."""
    try:
        HELPER.start()
    except Exception as exc:
        log.info("No helper process (%s)", exc)


def median_spacing(xyz: np.ndarray, reporter: Reporter) -> float | None:
    """The median spacing of ``xyz`` (N, 3), in the helper process."""
    return HELPER.median_spacing(np.ascontiguousarray(xyz), reporter)
