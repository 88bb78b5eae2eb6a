"""Colours of the verdict and of errors, the same in every panel and window."""

from __future__ import annotations

_STYLE = {
    "registered": "color: #1b6e20;",
    "accepted": "color: #1b6e20;",
    "needs review": "color: #9a6200;",
    "failed": "color: #c00000;",
}
#: An error message: dark red, readable on the light panels.
ERROR_STYLE = _STYLE["failed"]


def verdict_style(status: str) -> str:
    """A style sheet for a label that shows a verdict of ``status``."""
    return _STYLE.get(status, "")
