"""A row of controls that wraps onto a second line instead of widening the window.

The window must fit 1366x768: a row that does not fit its width goes on over more
lines, so every control stays in sight (a scrolling row would hide some of them).
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from PySide6.QtCore import QPoint, QRect, QSize, Qt
from PySide6.QtWidgets import (
    QLayout,
    QLayoutItem,
    QPushButton,
    QSizePolicy,
    QWidget,
)

if TYPE_CHECKING:
    from collections.abc import Callable


class FlowLayout(QLayout):
    """Lay widgets out left to right, starting a new line where the width ends.

    Qt's own flow layout example, without its spacers: a row's stretch has no
    meaning once it wraps.
    """

    def __init__(self, parent: QWidget | None = None) -> None:
        super().__init__(parent)
        self._items: list[QLayoutItem] = []

    def addItem(self, item: QLayoutItem) -> None:
        self._items.append(item)

    def count(self) -> int:
        return len(self._items)

    def itemAt(self, index: int) -> QLayoutItem | None:
        return self._items[index] if 0 <= index < len(self._items) else None

    def takeAt(self, index: int) -> QLayoutItem | None:
        return self._items.pop(index) if 0 <= index < len(self._items) else None

    def expandingDirections(self) -> Qt.Orientation:
        return Qt.Orientation(0)

    def hasHeightForWidth(self) -> bool:
        return True

    def heightForWidth(self, width: int) -> int:
        return self._arrange(QRect(0, 0, width, 0), move=False)

    def setGeometry(self, rect: QRect) -> None:
        super().setGeometry(rect)
        self._arrange(rect, move=True)

    def sizeHint(self) -> QSize:
        """One line of every control: what the row asks for when there is room."""
        shown = [i.sizeHint() for i in self._items if not i.isEmpty()]
        m = self.contentsMargins()
        width = sum(s.width() for s in shown) + self.spacing() * max(len(shown) - 1, 0)
        height = max((s.height() for s in shown), default=0)
        return QSize(width + m.left() + m.right(), height + m.top() + m.bottom())

    def minimumSize(self) -> QSize:
        """The widest single control: narrower than that, nothing can wrap."""
        size = QSize()
        for item in self._items:
            size = size.expandedTo(item.minimumSize())
        m = self.contentsMargins()
        return size + QSize(m.left() + m.right(), m.top() + m.bottom())

    def _arrange(self, rect: QRect, *, move: bool) -> int:
        """Place the items in ``rect`` (when ``move``); return the height used.

        Each control is centred in the height of its line, as a QHBoxLayout
        centres its controls.
        """
        m = self.contentsMargins()
        area = rect.adjusted(m.left(), m.top(), -m.right(), -m.bottom())
        gap = max(self.spacing(), 0)
        lines: list[list[tuple[QLayoutItem, int, QSize]]] = [[]]
        x = area.x()
        for item in self._items:
            if item.isEmpty():  # a hidden widget
                continue
            hint = item.sizeHint()
            if lines[-1] and x + hint.width() > area.right() + 1:
                lines.append([])
                x = area.x()
            lines[-1].append((item, x, hint))
            x += hint.width() + gap
        y = area.y()
        for n, line in enumerate(lines):
            height = max((hint.height() for _, _, hint in line), default=0)
            if move:
                for item, left, hint in line:
                    top = y + (height - hint.height()) // 2
                    item.setGeometry(QRect(QPoint(left, top), hint))
            y += height + (gap if n < len(lines) - 1 else 0)
        return y - rect.y() + m.bottom()


def wrapping_row(layout: FlowLayout) -> QWidget:
    """Return a widget holding ``layout``: a row that wraps when the window is narrow."""
    row = QWidget()
    row.setObjectName("control_row")
    row.setLayout(layout)
    policy = QSizePolicy(QSizePolicy.Policy.Preferred, QSizePolicy.Policy.Preferred)
    policy.setHeightForWidth(True)
    row.setSizePolicy(policy)
    return row


def add_look_buttons(
    bar: FlowLayout, tips: dict[str, str], look: Callable[[str], None]
) -> dict[str, QPushButton]:
    """Add a button per view name (``framing.LOOKS``) to ``bar`` calling ``look``."""
    buttons = {}
    for name, tip in tips.items():
        button = QPushButton(name)
        button.setToolTip(tip)
        button.clicked.connect(lambda _=False, n=name: look(n))
        bar.addWidget(button)
        buttons[name] = button
    return buttons
