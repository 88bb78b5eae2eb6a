"""Import, before the window shows, what the app's workers would import later.

A worker thread importing a module stalls the GUI thread (issue 15): loading a C
extension (``scipy.sparse._lil`` alone 0.1 s) holds the GIL for its whole set-up,
PySide's import hook reads the module's source, and the GUI thread itself waits
on the import lock whenever it needs one of those modules too. The first load of a
scan imported scipy.spatial (the Scans dock's spacing, 0.5 s of imports) and the
first Run all scipy's graph routines and small_gicp, each time while the window
was drawing. Importing them once at start-up (about half a second more before the
window appears) leaves nothing of the kind for later.
"""

from __future__ import annotations

import importlib
import logging
import time

log = logging.getLogger("amrst_gui.warmup")

# Modules the workers import inside functions (STYLE.md: heavy imports stay out of
# module level), found by listing sys.modules before and after opening a pair and
# running every step.
WORKER_MODULES = (
    "scipy.spatial",
    "scipy.sparse.csgraph",
    "matplotlib.colors",
    "amrst.io",
    "amrst.io.describe",
    "amrst.neighbours",
    "amrst.pipeline",
    "amrst.review.quality",
    "amrst.review.manual_keep",
    "amrst_gui.fine_job",
    "concurrent.futures.thread",
    "multiprocessing.shared_memory",
    "small_gicp",
)

_DONE = False


def import_worker_modules() -> float:
    """Import :data:`WORKER_MODULES` once per process; the seconds it took.

    A module that cannot be imported is skipped (the worker that needs it will
    report the failure where it matters). The helper process that describes big
    scans (``offload``) is not started here but with the first description: its
    imports, a second of CPU, slowed the reading of a scan opened at once.
    """
    global _DONE
    if _DONE:
        return 0.0
    start = time.perf_counter()
    for name in WORKER_MODULES:
        try:
            importlib.import_module(name)
        except ImportError as exc:
            log.debug("warm-up: %s not imported (%s)", name, exc)
    _DONE = True
    return time.perf_counter() - start
