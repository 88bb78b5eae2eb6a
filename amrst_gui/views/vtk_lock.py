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
"""

from __future__ import annotations

import threading

VTK_LOCK = threading.RLock()
