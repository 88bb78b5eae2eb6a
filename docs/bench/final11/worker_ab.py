"""The kept scan worker (``amrst/pipeline/scan_worker.py``) against the two threads.

``AMRST_SCAN_PROCESS`` picks the path at each call (0: the two threads). Each case
5 times per variant, the order alternating, the minimum counting (``scan_fork_ab``'s
loop, without its patch); the warm-up pair makes the worker serve from the first case.

Run: .venv/bin/python docs/bench/final11/worker_ab.py ../shared/data/cases ../shared/data/cases_field
"""

from __future__ import annotations

from scan_fork_ab import compare

if __name__ == "__main__":
    compare(
        {"threads": {"AMRST_SCAN_PROCESS": "0"}, "worker": {"AMRST_SCAN_PROCESS": "1"}}
    )
