"""Long number crunching of the Scans dock in a helper process (issue 15).

Describing a 10M-point scan takes seconds, most of it the median nearest-neighbour
spacing (sorts and k-d trees, slab by slab). In a worker thread every one of those
numpy and scipy calls competes with the GUI thread for the Python GIL, and each of
the many GIL hand-overs a frame needs (Qt and VTK release it on every call) waits
behind it: the window stalled 0.1-0.25 s while a scan was described, whatever the
slab size. A separate process has its own GIL; the operating system shares the
cores between it and the window fairly.

One helper process (``spawn``: no copy of the GUI's threads or Qt state) is
started with the window, so its imports are done before the first scan arrives.
The points go to it through shared memory (copied in chunks that release the
GIL), the answer comes back as one float. If the helper cannot run (no process
support, or it died), the work runs in the calling thread as before.
"""

from __future__ import annotations

import atexit
import logging
import multiprocessing
import threading
from concurrent.futures import ProcessPoolExecutor
from concurrent.futures import TimeoutError as FutureTimeout
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    from amrst.progress import Reporter

log = logging.getLogger("amrst_gui.offload")

# Rows copied into shared memory at once: 24 MB of float64, a few milliseconds.
COPY_ROWS = 1_000_000
_POLL_S = 0.1  # how often a waiting worker looks at Cancel

_LOCK = threading.Lock()
_POOL: ProcessPoolExecutor | None = None


def _pool() -> ProcessPoolExecutor:
    global _POOL
    with _LOCK:
        if _POOL is None:
            _POOL = ProcessPoolExecutor(
                max_workers=1, mp_context=multiprocessing.get_context("spawn")
            )
            atexit.register(shutdown)
        return _POOL


def start() -> None:
    """Start the helper process now and import what it needs (about 1 s, in the
    helper): the first description then starts at once. Never raises."""
    try:
        _pool().submit(_warm)
    except Exception as exc:  # no helper: descriptions run in their worker
        log.info("No helper process (%s); describing in a worker thread", exc)


def shutdown() -> None:
    """Stop the helper process without waiting for a description it runs."""
    global _POOL
    with _LOCK:
        pool, _POOL = _POOL, None
    if pool is None:
        return
    processes = list((getattr(pool, "_processes", None) or {}).values())
    pool.shutdown(wait=False, cancel_futures=True)
    for proc in processes:  # a description of 10M points would run on for seconds
        if proc.is_alive():
            proc.terminate()


def median_spacing(xyz: np.ndarray, reporter: Reporter) -> float | None:
    """``amrst.io.describe``'s median spacing of ``xyz`` (N, 3), computed in the
    helper process; raises ``Cancelled`` within ``_POLL_S`` of a Cancel."""
    from multiprocessing import shared_memory

    from amrst.io.describe import median_spacing as here

    xyz = np.ascontiguousarray(xyz)
    if len(xyz) < 2:
        return here(xyz)
    try:
        pool = _pool()
        shm = shared_memory.SharedMemory(create=True, size=xyz.nbytes)
    except Exception as exc:
        log.info("No helper process (%s); spacing computed in this thread", exc)
        return here(xyz)
    try:
        dst: np.ndarray = np.ndarray(xyz.shape, xyz.dtype, buffer=shm.buf)
        for i in range(0, len(xyz), COPY_ROWS):
            dst[i : i + COPY_ROWS] = xyz[i : i + COPY_ROWS]
            reporter.check_cancelled()
        del dst  # no view may outlive the mapping
        try:
            future = pool.submit(_spacing_in_helper, shm.name, xyz.shape, xyz.dtype.str)
        except Exception as exc:  # the helper died (BrokenProcessPool) or closed
            log.info("Helper process unavailable (%s); spacing computed here", exc)
            return here(xyz)
        while True:
            try:
                return future.result(timeout=_POLL_S)
            except FutureTimeout:
                if reporter.cancelled:
                    future.cancel()
                    reporter.check_cancelled()
    finally:
        shm.close()
        shm.unlink()  # the helper keeps its own mapping until it closes it


def _warm() -> None:
    """(In the helper.) Import the spacing code: numpy, scipy.spatial."""
    import amrst.io.describe  # noqa: F401


def _spacing_in_helper(name: str, shape: tuple[int, ...], dtype: str) -> float | None:
    """(In the helper.) The median spacing of the points in shared memory ``name``."""
    from multiprocessing import shared_memory

    from amrst.io.describe import median_spacing

    shm = shared_memory.SharedMemory(name=name)
    try:
        xyz: np.ndarray = np.ndarray(shape, np.dtype(dtype), buffer=shm.buf)
        try:
            return median_spacing(xyz)
        finally:
            del xyz
    finally:
        shm.close()
