"""One stem at one height, from above: where the technician judges a DBH, and measures
their own.

``TreeSliceView`` draws the slice's points, each in the colour of the scan it came
from, the measured DBH circle (solid at breast height, dashed elsewhere: there it is
only a yardstick) and the technician's own circle. While ``measuring``, a left click
adds a point of the stem's outline, a right click takes the last back, and the
circle through the points (``amrst.plot.review.hand_circle``) shows as it grows;
``clicks_changed`` tells each change, ``finished(keep)`` Enter (keep) or Esc.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np
from PySide6.QtCore import QPointF, QRectF, Qt, Signal
from PySide6.QtGui import QColor, QFont, QPainter, QPen
from PySide6.QtWidgets import QSizePolicy, QWidget

from amrst.plot.review import HandCircle, hand_circle
from amrst_gui.plot.stem_map import BACKGROUND, HAND_RGB, TEXT, scan_colour

if TYPE_CHECKING:
    from PySide6.QtGui import QKeyEvent, QMouseEvent

    from amrst.plot.view import TreeSlice

#: The box's half width (m) at least, and at most to take in the slice's points.
HALF_M = (0.1, 1.5)


class TreeSliceView(QWidget):
    """``set_slice``: a stem slice, the DBH circle and the technician's; ``measure``:
    collect clicks on the outline."""

    clicks_changed = Signal()
    finished = Signal(bool)

    def __init__(self, parent: QWidget | None = None) -> None:
        super().__init__(parent)
        self.setObjectName("tree_slice")
        self.setFocusPolicy(Qt.FocusPolicy.ClickFocus)  # Enter and Esc while measuring
        self.setMinimumSize(160, 160)
        policy = QSizePolicy(QSizePolicy.Policy.Expanding, QSizePolicy.Policy.Expanding)
        self.setSizePolicy(policy)
        self.slice: TreeSlice | None = None
        self.centre = np.zeros(2)
        self.radius_m = float("nan")
        self.fitted = True
        self.hand: HandCircle | None = None
        self.note = "Click a tree on the stem map."
        self.measuring = False
        self.clicks: list[tuple[float, float]] = []

    def set_slice(
        self,
        sl: TreeSlice | None,
        centre: np.ndarray,
        radius_m: float,
        note: str,
        fitted: bool = True,
        hand: HandCircle | None = None,
    ) -> None:
        """Show ``sl`` around ``centre`` with a circle of ``radius_m`` (dashed when
        not ``fitted`` at this height) and the technician's ``hand`` circle."""
        self.slice, self.centre, self.radius_m = sl, np.asarray(centre, float), radius_m
        self.note, self.fitted, self.hand = note, fitted, hand
        self.measure(False)
        self.update()

    def measure(self, on: bool) -> None:
        """Start (or stop) taking clicks; either way the clicks so far are dropped."""
        self.measuring = on and self.slice is not None
        self.clicks = []
        if self.measuring:
            self.setFocus()
        self.setCursor(
            Qt.CursorShape.CrossCursor if self.measuring else Qt.CursorShape.ArrowCursor
        )
        self.clicks_changed.emit()
        self.update()

    def to_px(self, xy: np.ndarray) -> np.ndarray:
        """Widget pixels of points ``xy`` (N, 2) in the slice's frame (m)."""
        box, scale = self._frame()
        d = (np.asarray(xy, float).reshape(-1, 2) - self.centre) * scale
        return np.column_stack([box.center().x() + d[:, 0], box.center().y() - d[:, 1]])

    def circle(self) -> HandCircle | None:
        """The circle through the clicks so far (None: too few, or on a line)."""
        return hand_circle(np.array(self.clicks)) if self.clicks else None

    # ------------------------------------------------------------- events
    def keyPressEvent(self, event: QKeyEvent) -> None:
        keys = {
            Qt.Key.Key_Return: True,
            Qt.Key.Key_Enter: True,
            Qt.Key.Key_Escape: False,
        }
        if self.measuring and event.key() in keys:
            self.finished.emit(keys[Qt.Key(event.key())])
        else:
            super().keyPressEvent(event)

    def mousePressEvent(self, event: QMouseEvent) -> None:
        if not self.measuring:
            super().mousePressEvent(event)
            return
        if event.button() == Qt.MouseButton.LeftButton:
            box, scale = self._frame()
            at = event.position()
            if not box.contains(at):
                return
            c = box.center()
            x = self.centre[0] + (at.x() - c.x()) / scale
            y = self.centre[1] - (at.y() - c.y()) / scale
            self.clicks.append((float(x), float(y)))
        elif event.button() == Qt.MouseButton.RightButton and self.clicks:
            self.clicks.pop()
        else:
            return
        self.clicks_changed.emit()
        self.update()

    def paintEvent(self, _event) -> None:
        p = QPainter(self)
        p.setRenderHint(QPainter.RenderHint.Antialiasing)
        p.fillRect(self.rect(), BACKGROUND)
        box, scale = self._frame()
        p.setPen(QColor(120, 120, 120))
        p.drawRect(box)
        p.setPen(TEXT)
        p.setFont(QFont(self.font().family(), 8))
        p.drawText(QPointF(6, self.height() - 5), self._note())
        if self.slice is not None:
            self._draw(p, box, scale)
        p.end()

    # ------------------------------------------------------------ drawing
    def _frame(self) -> tuple[QRectF, float]:
        """The square the slice is drawn in, and pixels per metre."""
        side = max(min(self.width(), self.height() - 18) - 8, 10)
        box = QRectF((self.width() - side) / 2, 4, side, side)
        return box, box.width() / (2 * self._half())

    def _half(self) -> float:
        """Half the box's width (m): 1.8 DBH radii, and wide enough for most of the
        points (a DBH too small for its stem would hide the bark one measures on)."""
        circle = 1.8 * self.radius_m if np.isfinite(self.radius_m) else HALF_M[0]
        if self.slice is None or not len(self.slice.xy):
            return max(circle, HALF_M[0])
        reach = 1.1 * np.percentile(np.hypot(*(self.slice.xy - self.centre).T), 95)
        return float(max(circle, min(reach, HALF_M[1]), HALF_M[0]))

    def _note(self) -> str:
        if not self.measuring:
            return self.note
        circle = self.circle()
        if circle is not None:
            return f"Yours: {100 * circle.dbh_m:.1f} cm ({len(self.clicks)} points)"
        return "Click 3 or more points on the stem's outline (right click: undo)"

    def _draw(self, p: QPainter, box: QRectF, scale: float) -> None:
        assert self.slice is not None

        def at(x: float, y: float) -> QPointF:
            return QPointF(*self.to_px(np.array([x, y]))[0])

        p.setClipRect(box)
        xy, scan = self.slice.xy, self.slice.scan
        step = max(1, len(xy) // 4000)
        for k in np.unique(scan):
            p.setPen(QPen(scan_colour(int(k)), 3))
            for qx, qy in xy[scan == k][::step]:
                point = at(qx, qy)
                if box.contains(point):
                    p.drawPoint(point)
        p.setBrush(Qt.BrushStyle.NoBrush)
        if np.isfinite(self.radius_m):
            pen = QPen(QColor(255, 255, 255), 1.5)
            if not self.fitted:
                pen.setStyle(Qt.PenStyle.DashLine)
            p.setPen(pen)
            r = self.radius_m * scale
            p.drawEllipse(at(*self.centre), r, r)
        hand = self.circle() if self.measuring else self.hand
        if hand is not None:
            p.setPen(QPen(QColor(*HAND_RGB), 2.5))
            r = hand.dbh_m / 2 * scale
            p.drawEllipse(at(*hand.centre_xy), r, r)
        p.setPen(QPen(QColor(*HAND_RGB), 2))
        for x, y in self.clicks:
            q = at(x, y)
            p.drawLine(q + QPointF(-4, -4), q + QPointF(4, 4))
            p.drawLine(q + QPointF(-4, 4), q + QPointF(4, -4))
        p.setClipping(False)
        p.setPen(TEXT)
        p.drawText(
            QPointF(box.left() + 4, box.top() + 12),
            f"box {2 * self._half() * 100:.0f} cm wide",
        )
