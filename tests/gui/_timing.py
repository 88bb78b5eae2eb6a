"""A helper of the GUI tests: how long another thread's work kept this one waiting."""

from __future__ import annotations

import threading
import time


def longest_gap_while(fn) -> tuple[float, object]:
    """Run ``fn`` in a thread; the longest gap between this thread's 1 ms ticks
    (the GUI thread's view of it: every tick needs the GIL), and what ``fn``
    returned or raised."""
    done = threading.Event()
    out: list = []

    def work() -> None:
        try:
            out.append(fn())
        except BaseException as exc:  # returned, so a failure cannot hang the test
            out.append(exc)
        finally:
            done.set()

    worker = threading.Thread(target=work)
    last = time.perf_counter()
    worker.start()
    longest = 0.0
    while not done.is_set():
        time.sleep(0.001)
        now = time.perf_counter()
        longest, last = max(longest, now - last), now
    worker.join()
    return longest, out[0]
