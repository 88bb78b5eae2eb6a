"""Colours of the verdict and of errors, the same in every panel and window."""

from __future__ import annotations

from amrst.review.verdict import REGISTERED, TEXT_RGB

_STYLE = {status: f"color: {rgb};" for status, rgb in TEXT_RGB.items()}
_STYLE["accepted"] = _STYLE[REGISTERED]
#: An error message: dark red, readable on the light panels.
ERROR_STYLE = _STYLE["failed"]


def verdict_style(status: str) -> str:
    """A style sheet for a label that shows a verdict of ``status``."""
    return _STYLE.get(status, "")
