"""A link between two scans, made up for the link-graph tests."""

from __future__ import annotations

import numpy as np

from amrst.multiscan.graph import Link
from amrst.types import make_transform


def link(a, b, verdict, weight=0.5, confidence=1.0, shift=None):
    """Link a-b with ``verdict``; its pose shifts by ``shift`` m (default b - a) in x."""
    return Link(
        a,
        b,
        verdict,
        weight,
        confidence,
        weight,
        make_transform(np.eye(3), [b - a if shift is None else shift, 0, 0]),
        None,
        "",
    )
