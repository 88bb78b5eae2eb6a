"""One lock between making VTK objects in worker threads and dropping them on the GUI thread.

A CI run of an earlier stop and a fresh-clone run hung for good in a test's teardown (found with
faulthandler's stacks and gdb, 2026-12-02). The GUI thread was closing a view:
``Renderer.RemoveAllViewProps`` destroyed an actor, VTK's garbage collector took its
global mutex and, on finalizing a data object whose Python wrapper was gone, called
back into Python (pyvista's ``DataObject.__del__``). That Python code let the GIL go
to a worker thread building a scene's ``pyvista.PolyData`` (``scene_jobs.prepare``),
which then waited for the collector's mutex while holding the GIL: each thread held
what the other waited for.

So the two never overlap: a worker holds :data:`VTK_LOCK` while it makes each VTK
object, and the GUI thread holds it while it replaces or removes a view's actors and
while it closes a view. Waiting for the lock releases the GIL, so whoever holds it
finishes. The GUI thread waits at most for one object being made (milliseconds).
A worker's result that nobody keeps (a stale scene) dies on the GUI thread under the
lock too (:func:`release_later`, called by ``amrst_gui.workers`` for every result).
"""

from __future__ import annotations

import threading

VTK_LOCK = threading.RLock()

# What the GUI thread lets go of a turn later, under the lock (see release_later).
_LATER: list[object] = []


def release_later(obj: object) -> None:
    """Hold ``obj`` until the next turn of the GUI event loop, then drop it under the lock.

    A worker's result reaches the GUI thread inside a queued signal, and Qt drops
    that signal's arguments after the slot returned: outside any lock. When nobody
    took the result (a scene made stale by a newer one, a job cancelled or
    discarded) that drop was the last one, and a ``Prepared`` full of VTK objects
    died there while another worker might be making some. Held here, its last
    reference goes under :data:`VTK_LOCK`. Call on the GUI thread.
    """
    from PySide6.QtCore import QTimer

    if not _LATER:
        QTimer.singleShot(0, _release)
    _LATER.append(obj)


def _release() -> None:
    with VTK_LOCK:
        _LATER.clear()
