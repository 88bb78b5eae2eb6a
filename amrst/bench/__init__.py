"""Benchmark: every method on every case, interleaved, with paper metrics and plots.

``run_bench`` is the library entry; ``configure_parser`` / ``run_cli`` are the hooks of
``amrst bench``. Reading cases and writing ``truth.json`` live in ``amrst.io.cases``.
"""

from __future__ import annotations

from amrst.bench.cli import TerminalProgress, configure_parser, run_cli
from amrst.bench.run import DEFAULT_METHODS, BenchResult, RunRecord, run_bench

__all__ = [
    "DEFAULT_METHODS",
    "BenchResult",
    "RunRecord",
    "TerminalProgress",
    "configure_parser",
    "run_bench",
    "run_cli",
]
