"""A row of controls that scrolls sideways instead of widening the window (issue 13:
the window must fit 1366x768)."""

from __future__ import annotations

from PySide6.QtCore import Qt
from PySide6.QtWidgets import QFrame, QHBoxLayout, QScrollArea, QWidget


def scrolling_row(layout: QHBoxLayout) -> QScrollArea:
    """Wrap ``layout`` in a one-row area that scrolls when the window is narrow."""
    inner = QWidget()
    inner.setLayout(layout)
    area = QScrollArea()
    area.setWidget(inner)
    area.setWidgetResizable(True)
    area.setFrameShape(QFrame.Shape.NoFrame)
    area.setVerticalScrollBarPolicy(Qt.ScrollBarPolicy.ScrollBarAlwaysOff)
    area.setHorizontalScrollBarPolicy(Qt.ScrollBarPolicy.ScrollBarAsNeeded)
    area.setFixedHeight(inner.sizeHint().height() + 14)
    return area
