"""Coordinates as the technician types them, and as the Plot window shows them."""

from __future__ import annotations

import re


def typed_numbers(text: str) -> list[str]:
    """Split typed numbers: spaces between them, a comma only before a space.

    "12,5 3" is two words, "12,5" and "3": a decimal comma is not read as two numbers.
    """
    return [w for w in re.split(r"\s*,\s+|\s+", text.strip()) if w]


def short_number(value: float) -> str:
    """A coordinate to the micrometre, without trailing zeros."""
    return f"{value:.6f}".rstrip("0").rstrip(".")
