"""Colours of the verdict, the same in every panel (status bar, Matches, Metrics)."""

from __future__ import annotations

_STYLE = {
    "registered": "color: #1b6e20;",
    "accepted": "color: #1b6e20;",
    "needs review": "color: #9a6200;",
    "failed": "color: #c00000;",
}


def verdict_style(status: str) -> str:
    """A style sheet for a label that shows a verdict of ``status``."""
    return _STYLE.get(status, "")
