"""The helper process of ``amrst_gui.offload``: ``python -m amrst_gui.offload_helper``.

Reads one JSON request per line on stdin (``{"shm": name, "shape": [N, 3],
"dtype": "<f8"}``: points in shared memory), answers one JSON line on stdout
(``{"spacing": float or null}`` or ``{"error": text}``), until stdin closes. No Qt,
no app: numpy, ``amrst.io.describe`` and ``amrst_gui.pacing`` (no Qt) only.
"""

from __future__ import annotations

import json
import sys


def serve() -> None:
    from multiprocessing import resource_tracker, shared_memory

    import numpy as np

    from amrst.io.describe import median_spacing
    from amrst_gui.pacing import at_least_nice

    # Background work: the window's own process goes first for the cores (not
    # more: started from a niced worker thread it already is).
    at_least_nice()
    for line in sys.stdin:
        try:
            ask = json.loads(line)
            shm = shared_memory.SharedMemory(name=ask["shm"])
            # The app owns the block and unlinks it; this process only reads it.
            resource_tracker.unregister(shm._name, "shared_memory")  # type: ignore[attr-defined]
            try:
                xyz: np.ndarray = np.ndarray(
                    tuple(ask["shape"]), np.dtype(ask["dtype"]), buffer=shm.buf
                )
                answer: dict = {"spacing": median_spacing(xyz)}
                del xyz
            finally:
                shm.close()
        except Exception as exc:  # answer, and stay up for the next request
            answer = {"error": f"{type(exc).__name__}: {exc}"}
        sys.stdout.write(json.dumps(answer) + "\n")
        sys.stdout.flush()


if __name__ == "__main__":
    serve()
