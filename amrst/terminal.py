"""Progress on the terminal for the command line (the one place that writes it)."""

from __future__ import annotations

import sys
import time


class TerminalReporter:
    """Progress on stderr: a bar on a terminal, a line per stage message otherwise."""

    def __init__(self, quiet: bool = False) -> None:
        self._tty = sys.stderr.isatty()
        self._quiet = quiet
        self._last = ""
        self._t0 = time.perf_counter()

    def progress(self, fraction: float, message: str = "") -> None:
        """Draw the bar, or write the message when its stage changed (unless quiet)."""
        if self._quiet:
            return
        if self._tty:
            bar = "#" * int(30 * fraction)
            sys.stderr.write(f"\r[{bar:<30}] {fraction:4.0%} {message[:50]:<50}")
            if fraction >= 1.0:
                sys.stderr.write("\n")
            sys.stderr.flush()
        elif message and message.split(":")[0] != self._last:
            self._last = message.split(":")[0]
            sys.stderr.write(f"{time.perf_counter() - self._t0:6.2f}s {message}\n")

    def check_cancelled(self) -> None:
        """Never cancel: Ctrl+C stops the command instead."""
