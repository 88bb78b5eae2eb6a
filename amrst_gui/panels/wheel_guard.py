"""A wheel over a spin box, slider or combo box in a scrolled dock scrolls the dock.

Qt gives wheel events to whatever input widget is under the cursor, so scrolling a
long dock changes the value the cursor happens to pass (a turn, a parameter) and
never moves the dock. A widget guarded here takes the wheel only once it has focus
(clicked or tabbed into); before that the wheel scrolls its scroll area.
"""

from __future__ import annotations

from PySide6.QtCore import QEvent, QObject, Qt
from PySide6.QtWidgets import (
    QAbstractScrollArea,
    QAbstractSlider,
    QAbstractSpinBox,
    QComboBox,
    QWidget,
)

_GUARDED = (QAbstractSpinBox, QAbstractSlider, QComboBox)


class WheelGuard(QObject):
    """Sends the wheel of an unfocused input widget to ``area`` instead."""

    def __init__(self, area: QAbstractScrollArea) -> None:
        super().__init__(area)
        self.area = area

    def guard(self, root: QWidget) -> None:
        """Guard every spin box, slider and combo box under ``root``."""
        for w in root.findChildren(QWidget):
            if isinstance(w, _GUARDED):
                w.setFocusPolicy(Qt.FocusPolicy.StrongFocus)  # the wheel gives none
                w.installEventFilter(self)

    def eventFilter(self, obj: QObject, event: QEvent) -> bool:
        if (
            event.type() == QEvent.Type.Wheel
            and isinstance(obj, QWidget)
            and not obj.hasFocus()
        ):
            self.area.wheelEvent(event)  # type: ignore[arg-type]
            return True
        return False
