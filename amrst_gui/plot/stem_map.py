"""The stem map of a plot seen from above.

``StemMapView`` draws every tree as its DBH circle to scale (a few pixels at least,
so a thin stem stays visible), filled by its DBH quality and ringed by the
technician's mark, with its id; the scan positions as triangles; the links between
them coloured by their state (dashed: not in the spanning tree); the vegetation's
density from above in grey under it all; the trees the technician added that no run
has measured yet as crosses. A click on a tree emits ``tree_clicked``; while
``adding``, a click anywhere emits ``point_clicked(x, y)`` in metres instead. The
wheel zooms about the cursor, a drag moves the map, a double click shows it whole.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np
from PySide6.QtCore import QPointF, QRectF, Qt, Signal
from PySide6.QtGui import (
    QColor,
    QFont,
    QFontMetrics,
    QImage,
    QPainter,
    QPen,
    QPolygonF,
)
from PySide6.QtWidgets import QSizePolicy, QWidget

# Fill of a tree by its DBH quality, ring by the technician's mark, link by its
# state: the plot report's colours.
from amrst.plot.report import MARK_RGB, QUALITY_RGB
from amrst.plot.report import STATE_RGB as LINK_RGB
from amrst.plot.review import NOT_A_TREE, PlotReview, listed_added
from amrst.plot.stemmap import StemMapParams

if TYPE_CHECKING:
    from amrst_gui.plot.jobs import PlotOutcome

BACKGROUND = QColor(31, 33, 38)
TEXT = QColor(230, 230, 230)
#: One colour per scan (repeats after eight).
SCAN_RGB = (
    (255, 183, 77),
    (79, 195, 247),
    (174, 213, 129),
    (240, 98, 146),
    (149, 117, 205),
    (77, 208, 225),
    (255, 241, 118),
    (161, 136, 127),
)
MIN_TREE_PX = 3.0
MAX_DBH_M = 20.0  # wider than any tree: a circle drawn no wider
SCAN_PX = 8.0  # half the width of a scanner's triangle
#: An added point this near a tree (m) is that tree, as a run finds it.
SAME_TREE_M = StemMapParams().same_stem_m
#: The technician's trees and circles: a colour no scan has.
HAND_RGB = (198, 255, 0)
CLICK_PX = 12.0
DRAG_PX = 4.0  # a press that moves farther is a drag of the map, not a click
MAX_ZOOM = 40.0  # times the whole plot's scale: a 20 cm stem some 60 px wide
KEY_PAN_SHARE = 0.1  # an arrow key moves the map by this share of its size
LEGEND_PX = 44.0  # the legend's band at the top


def scan_colour(k: int) -> QColor:
    """The colour of scan ``k`` (0-based) in the slice and the scan markers."""
    return QColor(*SCAN_RGB[k % len(SCAN_RGB)])


#: What the map says before any scan is open.
NO_PLOT = "No plot yet: open its scans (File ▸ Open plot…) and run it."


class StemMapView(QWidget):
    """The plot from above; ``set_plot(outcome)``, ``set_review``, ``select``."""

    tree_clicked = Signal(int)
    point_clicked = Signal(float, float)

    def __init__(self, parent: QWidget | None = None) -> None:
        super().__init__(parent)
        self.setObjectName("stem_map")
        self.setMinimumSize(320, 260)
        self.setSizePolicy(QSizePolicy.Policy.Expanding, QSizePolicy.Policy.Expanding)
        self.setFocusPolicy(Qt.FocusPolicy.StrongFocus)  # Tab reaches it: keys zoom
        self.outcome: PlotOutcome | None = None
        self.review = PlotReview()  # the technician's marks, DBHs and added trees
        self.adding = False
        self.selected: int | None = None
        self.empty_text = NO_PLOT  # what the map says while it has no plot
        self._image: QImage | None = None
        self.zoom = 1.0  # times the scale that shows the whole plot
        self._centre: np.ndarray | None = None  # (2,) m at the map's middle; None: fit
        self._drag: tuple[QPointF, np.ndarray] | None = None  # press, centre then
        self._dragging = False  # the press has moved farther than DRAG_PX
        self.setToolTip(
            "The plot from above: each tree is its DBH circle to scale (yours where "
            "you measured it; green ok, amber check, grey no DBH), ringed blue when "
            "marked ok, red when marked check, crossed when not a tree. Triangles are "
            "the scan positions, lines the links. Click a tree; the wheel zooms, a drag "
            "moves the map, a double click shows it whole. Keys: + and - zoom, the "
            "arrows move the map, 0 shows it whole, N and P the next and previous tree."
        )

    def set_plot(self, outcome: PlotOutcome | None) -> None:
        """Show ``outcome`` (None: nothing)."""
        self.outcome, self.selected = outcome, None
        self._image = None
        self.zoom, self._centre = 1.0, None
        top = None if outcome is None else outcome.top
        if top is not None:
            # White with the density as alpha: empty cells show the background, so
            # the map has no visible edge where the scans' extent ends.
            grey = top.image[::-1].astype(np.uint32)  # row 0 at the top
            argb = np.ascontiguousarray((grey << 24) | 0x00FFFFFF)
            h, w = grey.shape
            self._image = QImage(argb.data, w, h, 4 * w, QImage.Format.Format_ARGB32)
            self._image = self._image.copy()  # owns its pixels
        self.update()

    def set_review(self, review: PlotReview) -> None:
        """Draw the technician's marks and DBHs."""
        self.review = review
        self.update()

    def set_adding(self, on: bool) -> None:
        """Take the next click as where a tree stands (``point_clicked``)."""
        self.adding = on
        self.setCursor(Qt.CursorShape.CrossCursor if on else Qt.CursorShape.ArrowCursor)

    def pending(self) -> list[str]:
        """The ids of the added trees no run has listed yet."""
        if self.outcome is None:
            return []
        trees = {t.tree_id: t.stem.dbh_xy for t in self.outcome.trees}
        listed = listed_added(self.review, trees)
        return [k for k in self.review.added if k not in listed]

    def added_near(self, x: float, y: float) -> str | None:
        """The id of the added tree drawn within a few pixels of (x, y) m, or None."""
        added = self.review.added
        if not added:
            return None
        px = self.to_px(np.array(list(added.values())))
        d = np.hypot(*(px - self.to_px(np.array([x, y]))).T)
        n = int(np.argmin(d))
        return list(added)[n] if d[n] <= CLICK_PX else None

    def tree_near(self, x: float, y: float) -> int | None:
        """The listed tree standing within ``SAME_TREE_M`` of (x, y) m, or None."""
        if self.outcome is None or not self.outcome.trees:
            return None
        d = np.hypot(*(self.outcome.tree_xy.reshape(-1, 2) - (x, y)).T)
        k = int(np.argmin(d))
        return k if d[k] <= SAME_TREE_M else None

    def to_xy(self, x: float, y: float) -> tuple[float, float]:
        """Plot position (m) of the widget pixel (x, y)."""
        scale, centre, mid = self._mapping()
        return (
            float(centre[0] + (x - mid[0]) / scale),
            float(centre[1] + (self.height() - y - mid[1]) / scale),
        )

    def select(self, index: int | None) -> None:
        self.selected = index
        self.update()

    # ------------------------------------------------------------ geometry
    def _extent(self) -> tuple[np.ndarray, np.ndarray]:
        """Lower-left and upper-right corners (m) of the trees' crowns and the scans."""
        o = self.outcome
        assert o is not None
        half = np.array([t.stem.crown_width_m / 2 for t in o.trees], float)
        reach = np.fmax(np.nan_to_num(half, nan=0.0), 2.0)[:, None]
        scans = [s.xy[None] for s in o.scans if s.xy is not None]
        lows = [o.tree_xy - reach, *(xy - 2.0 for xy in scans)]
        highs = [o.tree_xy + reach, *(xy + 2.0 for xy in scans)]
        centre = o.area_xy
        if centre is not None and o.area is not None:  # the plot's edge in view
            lows.append(centre[None] - o.area.radius_m)
            highs.append(centre[None] + o.area.radius_m)
        if not any(len(p) for p in lows):
            return np.full(2, -2.0), np.full(2, 2.0)
        lo = np.vstack([p for p in lows if len(p)]).min(axis=0)
        hi = np.vstack([p for p in highs if len(p)]).max(axis=0)
        return lo, hi

    def _mapping(self) -> tuple[float, np.ndarray, np.ndarray]:
        """(pixels per m, the plot position at the map's middle, that middle in
        pixels from the bottom left) at the zoom asked for."""
        lo, hi = self._extent()
        margin = 30.0
        size = np.maximum(hi - lo, 1.0)
        scale = min(
            (self.width() - 2 * margin) / size[0],
            (self.height() - LEGEND_PX - 2 * margin) / size[1],
        )
        scale = max(scale, 1e-3) * self.zoom
        centre = lo + size / 2 if self._centre is None else self._centre
        mid = np.array([self.width(), self.height() - LEGEND_PX]) / 2
        return scale, centre, mid

    def to_px(self, xy: np.ndarray) -> np.ndarray:
        """(N, 2) plot positions (m) -> widget pixels."""
        scale, centre, mid = self._mapping()
        xy = np.asarray(xy, float).reshape(-1, 2)
        px = mid[0] + (xy[:, 0] - centre[0]) * scale
        py = self.height() - (mid[1] + (xy[:, 1] - centre[1]) * scale)
        return np.column_stack([px, py])

    def zoom_at(self, x: float, y: float, factor: float) -> None:
        """Zoom by ``factor`` keeping the plot position under pixel (x, y) there."""
        if self.outcome is None:
            return
        held = np.array(self.to_xy(x, y))
        self.zoom = float(np.clip(self.zoom * factor, 1.0, MAX_ZOOM))
        if self.zoom == 1.0:
            self._centre = None  # the whole plot again
        else:
            scale, _, mid = self._mapping()
            self._centre = (
                held - np.array([x - mid[0], self.height() - y - mid[1]]) / scale
            )
        self.update()

    def show_whole(self) -> None:
        """Show the whole plot again."""
        self.zoom, self._centre = 1.0, None
        self.update()

    def tree_at(self, x: float, y: float) -> int | None:
        """The tree drawn nearest the pixel (x, y), within its circle or a few px."""
        o = self.outcome
        if o is None or not o.trees:
            return None
        px = self.to_px(o.tree_xy)
        d = np.hypot(px[:, 0] - x, px[:, 1] - y)
        k = int(np.argmin(d))
        return k if d[k] <= max(CLICK_PX, self._radii_px()[k]) else None

    def _radii_px(self) -> np.ndarray:
        """(S,) each tree's circle on screen: its DBH (yours where you measured it)."""
        assert self.outcome is not None
        dbh = np.array(
            [
                t.stem.dbh_m
                if (h := self.review.dbh.get(t.tree_id)) is None
                else h.dbh_m
                for t in self.outcome.trees
            ],
            float,
        )
        # A DBH no tree has (a trees.csv edited by hand) draws no endless circle.
        dbh = np.clip(np.nan_to_num(dbh, nan=0.0), 0.0, MAX_DBH_M)
        return np.asarray(np.maximum(dbh / 2 * self._mapping()[0], MIN_TREE_PX))

    # -------------------------------------------------------------- events
    def mousePressEvent(self, event) -> None:
        if event.button() == Qt.MouseButton.LeftButton and self.outcome is not None:
            self._drag = (event.position(), self._mapping()[1].copy())
            self._dragging = False
        super().mousePressEvent(event)

    def mouseMoveEvent(self, event) -> None:
        """A drag moves the map, once it has gone farther than a click's jitter."""
        if self._drag is not None:
            start, centre = self._drag
            dx, dy = (event.position() - start).toTuple()
            self._dragging = self._dragging or bool(np.hypot(dx, dy) > DRAG_PX)
            if self._dragging:
                scale = self._mapping()[0]
                self._centre = centre - np.array([dx, -dy]) / scale
                self.update()
        super().mouseMoveEvent(event)

    def mouseReleaseEvent(self, event) -> None:
        """A press and release that did not drag is a click: a tree, or a point
        while adding."""
        pressed, self._drag = self._drag is not None, None
        left = event.button() == Qt.MouseButton.LeftButton
        if left and pressed and not self._dragging:
            pos = event.position()
            self._click(pos.x(), pos.y())
        super().mouseReleaseEvent(event)

    def _click(self, x: float, y: float) -> None:
        if self.adding:
            self.point_clicked.emit(*self.to_xy(x, y))
            return
        k = self.tree_at(x, y)
        if k is not None:
            self.tree_clicked.emit(k)

    def mouseDoubleClickEvent(self, event) -> None:
        if not self.adding:
            self.show_whole()
        super().mouseDoubleClickEvent(event)

    def keyPressEvent(self, event) -> None:
        """+ and - zoom at the middle, the arrows move the map, 0 shows it whole."""
        key = event.key()
        moves = {
            Qt.Key.Key_Left: (-1, 0),
            Qt.Key.Key_Right: (1, 0),
            Qt.Key.Key_Up: (0, 1),
            Qt.Key.Key_Down: (0, -1),
        }
        mid = self._mapping()[2] if self.outcome is not None else None
        if self.outcome is None:
            super().keyPressEvent(event)
        elif key in (Qt.Key.Key_Plus, Qt.Key.Key_Equal, Qt.Key.Key_Minus):
            assert mid is not None
            factor = 1.25 if key != Qt.Key.Key_Minus else 1 / 1.25
            self.zoom_at(mid[0], self.height() - mid[1], factor)
        elif key == Qt.Key.Key_0:
            self.show_whole()
        elif key in moves:
            scale, centre, _ = self._mapping()
            step = KEY_PAN_SHARE * min(self.width(), self.height()) / scale
            self._centre = centre + step * np.array(moves[key], float)
            self.update()
        else:
            super().keyPressEvent(event)

    def wheelEvent(self, event) -> None:
        steps = event.angleDelta().y() / 120.0
        if steps:
            pos = event.position()
            self.zoom_at(pos.x(), pos.y(), 1.25**steps)
        event.accept()

    def paintEvent(self, _event) -> None:
        p = QPainter(self)
        p.setRenderHint(QPainter.RenderHint.Antialiasing)
        p.fillRect(self.rect(), BACKGROUND)
        if self.hasFocus():  # the keys act on the map
            p.setPen(QPen(self.palette().highlight().color(), 2))
            p.drawRect(self.rect().adjusted(1, 1, -1, -1))
        p.setFont(self._map_font())
        if self.outcome is None:
            p.setPen(TEXT)
            p.drawText(
                self.rect(),
                Qt.AlignmentFlag.AlignCenter,
                self.empty_text,
            )
            p.end()
            return
        self._draw_top(p)
        self._draw_area(p)
        self._draw_links(p)
        self._draw_scans(p)
        self._draw_trees(p)
        self._draw_added(p)
        self._draw_scale(p)
        self._draw_legend(p)
        p.end()

    # ------------------------------------------------------------- drawing
    def _map_font(self) -> QFont:
        return QFont(self.font().family(), 8)

    def _draw_top(self, p: QPainter) -> None:
        top = None if self.outcome is None else self.outcome.top
        if top is None or self._image is None:
            return
        h, w = top.image.shape
        corners = self.to_px(
            np.array(
                [[top.x0, top.y0 + h * top.cell_m], [top.x0 + w * top.cell_m, top.y0]]
            )
        )
        p.setOpacity(0.45)
        p.drawImage(QRectF(QPointF(*corners[0]), QPointF(*corners[1])), self._image)
        p.setOpacity(1.0)

    def _draw_area(self, p: QPainter) -> None:
        """The fixed-radius plot's edge, dashed, and its centre."""
        o = self.outcome
        centre = None if o is None else o.area_xy
        if centre is None or o is None or o.area is None:
            return
        (x, y), r = self.to_px(centre)[0], o.area.radius_m * self._mapping()[0]
        pen = QPen(TEXT, 1.5)
        pen.setStyle(Qt.PenStyle.DashLine)
        p.setPen(pen)
        p.setBrush(Qt.BrushStyle.NoBrush)
        p.drawEllipse(QPointF(x, y), r, r)
        p.drawLine(QPointF(x - 5, y), QPointF(x + 5, y))
        p.drawLine(QPointF(x, y - 5), QPointF(x, y + 5))

    def _draw_links(self, p: QPainter) -> None:
        assert self.outcome is not None
        scans = self.outcome.scans
        for link in self.outcome.links:
            a, b = scans[link.target].xy, scans[link.source].xy
            if a is None or b is None:
                continue
            pen = QPen(QColor(LINK_RGB.get(link.status, "#c8c8c8")))
            pen.setWidthF(3.0 if link.in_tree else 1.5)
            if not link.in_tree:
                pen.setStyle(Qt.PenStyle.DashLine)
            p.setPen(pen)
            (x0, y0), (x1, y1) = self.to_px(np.array([a, b]))
            p.drawLine(QPointF(x0, y0), QPointF(x1, y1))

    def _draw_scans(self, p: QPainter) -> None:
        assert self.outcome is not None
        for k, scan in enumerate(self.outcome.scans):
            if scan.xy is None:
                continue
            (x, y), s = self.to_px(scan.xy)[0], SCAN_PX
            tri = QPolygonF(
                [
                    QPointF(x, y - s),
                    QPointF(x - s, y + s * 0.7),
                    QPointF(x + s, y + s * 0.7),
                ]
            )
            p.setPen(QPen(QColor(20, 20, 20), 1))
            p.setBrush(scan_colour(k))
            p.drawPolygon(tri)
            p.setPen(TEXT)
            p.drawText(self._scan_label_at(x, y), f"S{k + 1}")

    def _scan_label_at(self, x: float, y: float) -> QPointF:
        """Where the label of a scanner drawn at pixel (x, y) goes."""
        return QPointF(x + SCAN_PX + 2, y + 4)

    def _draw_trees(self, p: QPainter) -> None:
        assert self.outcome is not None
        px = self.to_px(self.outcome.tree_xy)
        radii = self._radii_px()
        for k, tree in enumerate(self.outcome.trees):
            x, y = px[k]
            r = float(radii[k])
            rgb = QUALITY_RGB.get(tree.stem.dbh_quality, QUALITY_RGB["none"])
            mark = self.review.marks.get(tree.tree_id)
            ring = QPen(QColor(MARK_RGB[mark]) if mark else QColor(15, 15, 15))
            ring.setWidthF(2.5 if mark else 1.0)
            p.setPen(ring)
            p.setBrush(QColor(rgb))
            p.drawEllipse(QPointF(x, y), r, r)
            if mark == NOT_A_TREE:
                p.setPen(QPen(QColor(MARK_RGB[mark]), 2.0))
                d = max(r, 5.0)
                p.drawLine(QPointF(x - d, y - d), QPointF(x + d, y + d))
                p.drawLine(QPointF(x - d, y + d), QPointF(x + d, y - d))
            if k == self.selected:
                p.setBrush(Qt.BrushStyle.NoBrush)
                p.setPen(QPen(QColor(255, 235, 59), 2.0))
                p.drawEllipse(QPointF(x, y), r + 6, r + 6)
        self._draw_tree_labels(p, px, radii)

    def _draw_tree_labels(self, p: QPainter, px: np.ndarray, radii: np.ndarray) -> None:
        assert self.outcome is not None
        p.setPen(TEXT)
        for k, at in self.tree_labels(px, radii):
            p.drawText(at, self.outcome.trees[k].tree_id)

    def tree_labels(
        self, px: np.ndarray, radii: np.ndarray | None = None
    ) -> list[tuple[int, QPointF]]:
        """Where each tree's label goes (``px``, ``radii``: the trees on screen).

        The selected tree's is always drawn; the others, widest first, are left out
        where they would cover a scanner's label, an added tree's or one already
        placed (zooming in makes room for them).
        """
        assert self.outcome is not None
        radii = self._radii_px() if radii is None else radii
        order = sorted(range(len(radii)), key=lambda k: (k != self.selected, -radii[k]))
        metrics = QFontMetrics(self._map_font())
        placed: list[tuple[int, QPointF]] = []
        boxes = self._fixed_labels(metrics)
        for k in order:
            at = QPointF(px[k][0] + float(radii[k]) + 3, px[k][1] - 3)
            box = QRectF(metrics.boundingRect(self.outcome.trees[k].tree_id))
            box.translate(at)
            if k == self.selected or not any(box.intersects(o) for o in boxes):
                boxes.append(box)
                placed.append((k, at))
        return placed

    def _draw_added(self, p: QPainter) -> None:
        """The added trees no run has measured yet: crosses, named as they will be."""
        pen = QPen(QColor(*HAND_RGB), 2.0)
        for tree_id in self.pending():
            x, y = self.to_px(np.array(self.review.added[tree_id]))[0]
            p.setPen(pen)
            p.drawLine(QPointF(x - 6, y), QPointF(x + 6, y))
            p.drawLine(QPointF(x, y - 6), QPointF(x, y + 6))
            p.drawText(QPointF(x + 8, y - 3), f"{tree_id} (next run)")

    def _fixed_labels(self, metrics: QFontMetrics) -> list[QRectF]:
        """Where the labels drawn whatever the trees' go: the scanners' and those of
        the trees added by hand that no run has measured yet."""
        assert self.outcome is not None
        boxes = [
            QRectF(metrics.boundingRect(f"S{k + 1}")).translated(
                self._scan_label_at(*self.to_px(s.xy)[0])
            )
            for k, s in enumerate(self.outcome.scans)
            if s.xy is not None
        ]
        for tree_id in self.pending():
            x, y = self.to_px(np.array(self.review.added[tree_id]))[0]
            text = f"{tree_id} (next run)"
            boxes.append(QRectF(metrics.boundingRect(text)).translated(x + 8, y - 3))
        return boxes

    def _draw_scale(self, p: QPainter) -> None:
        scale = self._mapping()[0]
        steps = (0.1, 0.2, 0.5, 1, 2, 5, 10, 20, 50)
        metres = next((m for m in steps if m * scale >= 60), 100)
        x0, y0 = 12.0, self.height() - 12.0
        p.setPen(QPen(TEXT, 2))
        p.drawLine(QPointF(x0, y0), QPointF(x0 + metres * scale, y0))
        p.drawText(QPointF(x0, y0 - 5), f"{metres:g} m   (the reference scan's x, y)")

    def _has_area(self) -> bool:
        return self.outcome is not None and self.outcome.area is not None

    def _draw_legend(self, p: QPainter) -> None:
        """DBH quality fills, mark rings and link states, in the top-left corner."""
        band = QColor(BACKGROUND)
        band.setAlpha(215)  # over a zoomed map's trees, still readable
        p.fillRect(QRectF(0, 0, self.width(), LEGEND_PX + 4), band)
        x, y, step = 10.0, 14.0, 15.0
        p.setPen(TEXT)
        p.drawText(QPointF(x, y), "DBH:")
        cx = x + 34
        for name, rgb in QUALITY_RGB.items():
            p.setPen(QPen(QColor(15, 15, 15), 1))
            p.setBrush(QColor(rgb))
            p.drawEllipse(QPointF(cx + 5, y - 4), 5, 5)
            p.setPen(TEXT)
            p.drawText(QPointF(cx + 13, y), name)
            cx += 22 + 7 * len(name)
        if self._has_area():
            pen = QPen(TEXT, 1.5)
            pen.setStyle(Qt.PenStyle.DashLine)
            p.setPen(pen)
            p.drawLine(QPointF(cx + 10, y - 4), QPointF(cx + 34, y - 4))
            p.setPen(TEXT)
            p.drawText(QPointF(cx + 40, y), "the plot's edge")
        y += step
        p.drawText(QPointF(x, y), "Links:")
        cx = x + 40
        for name, rgb in LINK_RGB.items():
            p.setPen(QPen(QColor(rgb), 3))
            p.drawLine(QPointF(cx, y - 4), QPointF(cx + 16, y - 4))
            p.setPen(TEXT)
            p.drawText(QPointF(cx + 20, y), name)
            cx += 30 + 7 * len(name)
        y += step
        p.drawText(
            QPointF(x, y),
            "Solid: the spanning tree; your mark: ring blue ok, red check; "
            "cross: not a tree",
        )
