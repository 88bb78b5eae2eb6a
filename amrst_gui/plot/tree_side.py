"""One tree seen from the side: its points, its height and its DBH to scale.

The technician checks there what the figures rest on: whether the top the height
reaches is the tree's (or a neighbour's crown was taken in, or the top was hidden),
and where breast height falls on the stem. Seen from the south (x east, z up), the
stem at 0, the ground at its base at 0; a tree whose top stands ``ASIDE_M`` or more
off its foot is seen with its top to the right instead, so that a lean shows.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np
from PySide6.QtCore import QPointF, QRectF, Qt
from PySide6.QtGui import QColor, QFont, QPainter, QPen, QPolygonF
from PySide6.QtWidgets import QSizePolicy, QWidget

from amrst.plot.diameter import BREAST_HEIGHT_M
from amrst.plot.flags import height_words
from amrst_gui.plot.stem_map import BACKGROUND, HAND_RGB, TEXT, scan_colour

if TYPE_CHECKING:
    from amrst.plot.inventory import Tree
    from amrst.plot.review import HandCircle
    from amrst.plot.view import TreeProfile

HAND = QColor(*HAND_RGB)
#: Room around the tree (m) and for the labels (px).
MARGIN_M = 0.5
LABEL_PX = 18.0
# Behind the height labels: the background, a little see-through.
LABEL_SHADE = QColor(BACKGROUND.red(), BACKGROUND.green(), BACKGROUND.blue(), 200)
ASIDE_M = 0.5


def across(base_xy: np.ndarray, xyz: np.ndarray) -> tuple[np.ndarray, str]:
    """The horizontal axis (2,) a side view draws, and how the tree is seen.

    East, seen from the south; toward the tree's top (the middle of its points in
    its highest half metre, so a stray point does not turn it) when that stands
    ``ASIDE_M`` or more off the stem's foot.
    """
    if len(xyz):
        high = xyz[xyz[:, 2] >= xyz[:, 2].max() - 0.5, :2]
        off = np.median(high, axis=0) - base_xy
        length = float(np.hypot(off[0], off[1]))
        if length >= ASIDE_M:
            return off / length, "seen with its top to the right"
    return np.array([1.0, 0.0]), "seen from the south"


class TreeSideView(QWidget):
    """``set_tree(tree, profile, hand)``: the tree's points by scan, the ground, the
    height line, and the DBH bars at breast height (white measured, green yours)."""

    def __init__(self, parent: QWidget | None = None) -> None:
        super().__init__(parent)
        self.setObjectName("tree_side")
        self.setMinimumSize(160, 160)
        policy = QSizePolicy(QSizePolicy.Policy.Expanding, QSizePolicy.Policy.Expanding)
        self.setSizePolicy(policy)
        self.tree: Tree | None = None
        self.profile: TreeProfile | None = None
        self.hand: HandCircle | None = None

    def set_tree(
        self,
        tree: Tree | None,
        profile: TreeProfile | None,
        hand: HandCircle | None = None,
    ) -> None:
        """Show ``tree`` from its ``profile`` points (None: nothing), with the
        technician's ``hand`` DBH."""
        self.tree, self.profile, self.hand = tree, profile, hand
        self.update()

    def paintEvent(self, _event) -> None:
        p = QPainter(self)
        p.setRenderHint(QPainter.RenderHint.Antialiasing)
        p.fillRect(self.rect(), BACKGROUND)
        p.setFont(QFont(self.font().family(), 8))
        if self.tree is not None and self.profile is not None:
            self._draw(p, self.tree, self.profile)
        else:
            p.setPen(TEXT)
            p.drawText(QPointF(6, self.height() - 5), "Click a tree on the stem map.")
        p.end()

    def _draw(self, p: QPainter, tree: Tree, profile: TreeProfile) -> None:
        stem = tree.stem
        base_xy, base_z = np.asarray(stem.base[:2], float), float(stem.base[2])
        axis, seen = across(base_xy, profile.xyz)
        dx = (profile.xyz[:, :2] - base_xy) @ axis
        dz = profile.xyz[:, 2] - base_z
        top = float(np.nanmax([stem.seen_to_m, dz.max(initial=0.0), 2.0]))
        half = max(float(np.abs(dx).max(initial=0.0)), 1.0) + MARGIN_M
        box = QRectF(4, 4, self.width() - 8, self.height() - 8 - LABEL_PX)
        scale = min(box.width() / (2 * half), box.height() / (top + 2 * MARGIN_M))
        cx = box.center().x()
        ground = box.bottom() - MARGIN_M * scale

        def at(x: float, z: float) -> QPointF:
            return QPointF(cx + x * scale, ground - z * scale)

        p.setPen(QPen(QColor(120, 120, 120), 1))
        p.drawLine(at(-half, 0.0), at(half, 0.0))
        labels = self._draw_heights(p, at(-half, 0.0), top, scale)
        for k in np.unique(profile.scan):
            p.setPen(QPen(scan_colour(int(k)), 2))
            mine = profile.scan == k
            p.drawPoints(
                QPolygonF([at(x, z) for x, z in zip(dx[mine], dz[mine], strict=True)])
            )
        p.setPen(TEXT)
        for where, text in labels:  # over the points, on a shade: always legible
            rect = p.fontMetrics().boundingRect(text).translated(where.toPoint())
            p.fillRect(rect.adjusted(-1, 0, 1, 0), LABEL_SHADE)
            p.drawText(where, text)
        line = stem.seen_to_m  # the height, or how high a tree out of range was seen
        if np.isfinite(line):
            pen = QPen(QColor(255, 255, 255), 1)
            pen.setStyle(Qt.PenStyle.DashLine)
            p.setPen(pen)
            p.drawLine(at(-half, line), at(half, line))
            p.setPen(TEXT)
            words = height_words(stem.height_m, stem.height_seen_m)
            p.drawText(
                at(-half, line) + QPointF(2, -3),
                f"height {words} m ({stem.height_flag})",
            )
        bars = [
            (np.asarray(stem.dbh_xy, float), stem.dbh_m, QColor(255, 255, 255), 0.0)
        ]
        if self.hand is not None:  # just above the measured one
            hand_xy = np.asarray(self.hand.centre_xy, float)
            bars.append((hand_xy, self.hand.dbh_m, HAND, 5.0 / scale))
        for xy, dbh, colour, lift in bars:
            if np.isfinite(dbh):
                x = float((xy - base_xy) @ axis)
                z = BREAST_HEIGHT_M + lift
                p.setPen(QPen(colour, 3))
                p.drawLine(at(x - dbh / 2, z), at(x + dbh / 2, z))
        p.setPen(TEXT)
        p.drawText(
            QPointF(6, self.height() - 5),
            f"{len(profile.xyz):,} of {stem.n_points:,} points shown; "
            + ("bars: DBH, green yours" if self.hand is not None else "bar: DBH"),
        )
        corner = QRectF(0, self.height() - 5 - 2 * LABEL_PX, self.width() - 6, LABEL_PX)
        p.drawText(
            corner, Qt.AlignmentFlag.AlignRight | Qt.AlignmentFlag.AlignBottom, seen
        )

    def _draw_heights(
        self, p: QPainter, ground: QPointF, top: float, scale: float
    ) -> list[tuple[QPointF, str]]:
        """A height scale up the left edge: a tick every 2 m (5 m on a tall tree).

        Returns its labels, drawn after the points.
        """
        step = 2.0 if top < 12 else 5.0
        p.setPen(QPen(QColor(150, 150, 150), 1))
        p.drawLine(ground, ground - QPointF(0, top * scale))
        labels = []
        for z in np.arange(step, top + 1e-9, step):
            y = ground.y() - z * scale
            p.drawLine(QPointF(ground.x(), y), QPointF(ground.x() + 5, y))
            labels.append((QPointF(ground.x() + 7, y + 4), f"{z:g} m"))
        return labels
