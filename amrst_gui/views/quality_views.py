"""Quality views: distance histogram with its colour bar, stem slices.

``DistanceHistogram`` draws the distances of the overlay's distance colouring: each bar
in the colour its points have in the 3D view, with the scale in cm under it.
``StemSlicesView`` draws horizontal slices at heights above the tree base, both scans
in their colours, the fitted circle of each and the centre offset in mm.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np
from PySide6.QtCore import QPointF, QRectF, Qt
from PySide6.QtGui import QColor, QFont, QPainter, QPen
from PySide6.QtWidgets import QSizePolicy, QWidget

from amrst_gui.views.scene import (
    DISTANCE_CLIP_M,
    SOURCE_RGB,
    TARGET_RGB,
    distance_rgb,
    shown_coarse,
)
from amrst_gui.views.scene_jobs import SYNC_POINTS

if TYPE_CHECKING:
    from amrst_gui.workers import StageJob

_BINS = 25


class DistanceHistogram(QWidget):
    """Histogram of point-to-other-scan distances (cm), bars coloured like the points."""

    def __init__(self, parent=None) -> None:
        super().__init__(parent)
        self.setObjectName("distance_histogram")
        self.setMinimumHeight(70)
        self.setMaximumHeight(90)
        self.setSizePolicy(QSizePolicy.Policy.Expanding, QSizePolicy.Policy.Fixed)
        self.distances = np.zeros(0)
        self.headline = ""
        self._tip = (
            "Distance from each point to the nearest point of the other scan, both "
            "ways, where both scans saw the scene (points only one scan saw are grey "
            "and left out). A right pose: most points under 1-2 cm (scan noise)."
        )
        self.setToolTip(self._tip)

    def set_distances(self, distances: np.ndarray, headline: str = "") -> None:
        """Show ``distances`` (m); ``headline``: the registration's own figures
        (the Quality table's), shown before the drawn points' own."""
        self.distances = np.asarray(distances, float)
        self.headline = headline
        self.update()

    def summary(self) -> str:
        d = self.distances[np.isfinite(self.distances)]
        if not len(d):
            return self.headline
        drawn = (
            f"median {np.median(d) * 100:.1f} cm, 95th pct. "
            f"{np.percentile(d, 95) * 100:.1f} cm, within 2 cm {np.mean(d < 0.02):.0%}"
        )
        # The registration's own figures when known (the drawn points' in the
        # tooltip): one line that fits the view's width.
        self.setToolTip(f"{self._tip}\nPoints drawn, where both scans saw: {drawn}.")
        return self.headline or f"where both scans saw: {drawn}"

    def paintEvent(self, _event) -> None:
        p = QPainter(self)
        p.fillRect(self.rect(), QColor(40, 42, 48))
        w, h = self.width(), self.height()
        d = np.minimum(self.distances[np.isfinite(self.distances)], DISTANCE_CLIP_M)
        p.setPen(QColor(230, 230, 230))
        p.setFont(QFont(self.font().family(), 8))
        if not len(d):
            p.drawText(
                6, h // 2, "Distance colouring: choose it above to see the histogram."
            )
            p.end()
            return
        counts, edges = np.histogram(d, bins=_BINS, range=(0, DISTANCE_CLIP_M))
        top, bottom = 16, h - 16
        bar_w = (w - 12) / _BINS
        mids = (edges[:-1] + edges[1:]) / 2
        rgb = distance_rgb(mids)
        peak = max(int(counts.max()), 1)
        for i, c in enumerate(counts):
            bh = (bottom - top) * c / peak
            p.fillRect(
                QRectF(6 + i * bar_w, bottom - bh, bar_w - 1, bh),
                QColor(*(int(v) for v in rgb[i])),
            )
        for cm in (0, 2.5, 5, 7.5, 10):
            x = 6 + (w - 12) * cm / (DISTANCE_CLIP_M * 100)
            label = f"≥{cm:g} cm" if cm == 10 else f"{cm:g} cm"
            p.drawText(QPointF(min(x, w - 44), h - 3), label)
        p.drawText(6, 12, "Distances: " + self.summary())
        p.end()


class SlicePlot(QWidget):
    """One slice drawn to fit its box: both scans' points and their circles."""

    def __init__(self, sl, parent=None) -> None:
        super().__init__(parent)
        self.slice = sl
        self.setMinimumSize(120, 120)
        policy = QSizePolicy(QSizePolicy.Policy.Expanding, QSizePolicy.Policy.Preferred)
        policy.setHeightForWidth(True)
        self.setSizePolicy(policy)

    def hasHeightForWidth(self) -> bool:
        return True

    def heightForWidth(self, width: int) -> int:
        return width  # square: as tall as the column is wide

    def plot_rect(self) -> QRectF:
        """The square the slice is drawn in: as large as the widget allows."""
        side = max(min(self.width(), self.height()) - 4, 10)
        return QRectF((self.width() - side) / 2, (self.height() - side) / 2, side, side)

    def paintEvent(self, _event) -> None:
        p = QPainter(self)
        p.fillRect(self.rect(), QColor(31, 33, 38))
        _draw_slice(p, self.slice, self.plot_rect())
        p.end()


def _draw_slice(p: QPainter, sl, box: QRectF) -> None:
    pts = [a for a in (sl.target_xy, sl.source_xy) if len(a)]
    circles = [c for c in (sl.target_circle, sl.source_circle) if c is not None]
    p.setPen(QColor(120, 120, 120))
    p.drawRect(box)
    if not pts:
        return
    allp = np.vstack(pts)
    if circles:
        c = np.array(circles[0].centre_xy)
        half = max(max(ci.radius_m for ci in circles) * 1.8, 0.05)
    else:
        c = np.median(allp, axis=0)
        half = max(float(np.percentile(np.abs(allp - c), 95)), 0.05)
    scale = box.width() / (2 * half)

    def to_px(xy):
        return (
            box.center().x() + (xy[0] - c[0]) * scale,
            box.center().y() - (xy[1] - c[1]) * scale,
        )

    for xy, rgb in ((sl.target_xy, TARGET_RGB), (sl.source_xy, SOURCE_RGB)):
        p.setPen(QPen(QColor(*rgb), 2))
        for q in xy[:: max(1, len(xy) // 3000)]:
            x, y = to_px(q)
            if box.contains(QPointF(x, y)):
                p.drawPoint(QPointF(x, y))
    p.setBrush(Qt.BrushStyle.NoBrush)
    for circle, rgb in (
        (sl.target_circle, TARGET_RGB),
        (sl.source_circle, SOURCE_RGB),
    ):
        if circle is None:
            continue
        p.setPen(QPen(QColor(*rgb), 1.5))
        x, y = to_px(circle.centre_xy)
        r = circle.radius_m * scale
        p.drawEllipse(QPointF(x, y), r, r)


_NOTE_STYLE = "color: #e6e6e6;"
_WARN_STYLE = "color: #ff8a80; font-weight: bold;"


class StemSlicesView(QWidget):
    """Stem slices side by side; set with ``set_slices(list of StemSlice)``.

    Each slice is a plot with its two caption lines in labels under it (word-wrapped,
    in their own column, so captions never overlap); the plots take the height left.
    A slice whose circle fit cannot be trusted says so instead of an offset.
    """

    def __init__(self, parent=None) -> None:
        from PySide6.QtWidgets import QHBoxLayout, QLabel, QVBoxLayout

        super().__init__(parent)
        self.setObjectName("stem_slices")
        self.setAutoFillBackground(True)
        pal = self.palette()
        pal.setColor(self.backgroundRole(), QColor(31, 33, 38))
        self.setPalette(pal)
        self.slices: list = []
        self.caption = "No registration to slice yet."
        self.caption_label = QLabel(self.caption)
        self.caption_label.setWordWrap(True)
        self.caption_label.setStyleSheet(_NOTE_STYLE)
        self.row = QHBoxLayout()
        self.row.setSpacing(8)
        layout = QVBoxLayout(self)
        layout.setContentsMargins(8, 6, 8, 6)
        layout.addWidget(self.caption_label)
        layout.addLayout(self.row, 1)
        self.cells: list[QWidget] = []
        self.setMinimumSize(300, 200)

    def set_slices(self, slices: list, caption: str) -> None:
        from PySide6.QtWidgets import QLabel, QVBoxLayout

        self.slices, self.caption = list(slices), caption
        self.caption_label.setText(caption)
        self.setToolTip(
            "Horizontal slices at heights above the tree base: amber target, blue "
            "source, each scan's circle at the radius of both. Good: the circles "
            "coincide, centres under 15 mm apart; ghosting "
            "that grows with height is wind, not misregistration. A circle resting "
            "on few points, a short arc or a flared base is marked unreliable."
        )
        for cell in self.cells:
            # Off the view at once: deleteLater alone leaves the old cell a visible
            # child of the view, drawn with the new ones until Qt gets to delete it.
            cell.setParent(None)
            cell.deleteLater()
        self.cells = []
        for sl in self.slices:
            cell = QWidget(self)
            cell.setObjectName("slice_cell")
            box = QVBoxLayout(cell)
            box.setContentsMargins(0, 0, 0, 0)
            box.setSpacing(2)
            box.addWidget(SlicePlot(sl, cell))
            title, note = sl.caption()
            for text, style in (
                (title, _NOTE_STYLE),
                (note, _WARN_STYLE if sl.problem() else _NOTE_STYLE),
            ):
                label = QLabel(text, cell)
                label.setWordWrap(True)
                label.setStyleSheet(style)
                label.setToolTip(text)
                box.addWidget(label)
            box.addStretch(1)
            self.row.addWidget(cell, 1)
            self.cells.append(cell)

    def captions(self) -> list[tuple[str, str]]:
        """The two caption lines of each slice, as shown."""
        return [sl.caption() for sl in self.slices]

    def offsets_mm(self) -> list[float]:
        """Centre offset of each slice (mm; NaN without two circles)."""
        return [s.offset_m * 1000 for s in self.slices]


class StemSlicesPane(QWidget):
    """Heights and thickness above a StemSlicesView of the session's best result,
    or of the candidate selected in the Matches list (as the *After coarse* overlay
    previews it).

    Listens to ``coarse_accepted``, ``fine_finished``, ``scan_loaded``,
    ``scans_swapped``, ``matches_changed``, ``selection_changed`` and
    ``review_changed``; emits nothing.
    """

    def __init__(self, session, parent=None) -> None:
        from PySide6.QtWidgets import QHBoxLayout, QLabel, QLineEdit, QVBoxLayout

        super().__init__(parent)
        self.setObjectName("stem_slices_pane")
        self.session = session
        self._job: StageJob | None = None  # the slicing in a worker (big scans)
        self.heights = QLineEdit("0.3, 1.3, 3")
        self.heights.setToolTip("Heights above the tree base (m), separated by commas")
        self.thickness = QLineEdit("10")
        self.thickness.setToolTip("Slice thickness (cm)")
        self.thickness.setMaximumWidth(50)
        for edit in (self.heights, self.thickness):
            edit.editingFinished.connect(self.refresh)
        bar = QHBoxLayout()
        bar.setContentsMargins(4, 2, 4, 2)
        bar.addWidget(QLabel("Heights (m):"))
        bar.addWidget(self.heights, 1)
        bar.addWidget(QLabel("Thickness (cm):"))
        bar.addWidget(self.thickness)
        self.view = StemSlicesView(self)
        layout = QVBoxLayout(self)
        layout.setContentsMargins(0, 0, 0, 0)
        layout.addLayout(bar)
        layout.addWidget(self.view, 1)
        for name in (
            "coarse_accepted",
            "fine_finished",
            "scan_loaded",
            "scans_swapped",
            "matches_changed",
            "selection_changed",
            "review_changed",
        ):
            getattr(session, name).connect(self._on_result)

    def refresh(self) -> None:
        """Slice both scans under the pose :func:`_slice_pose` picks."""
        s = self.session
        if s.plot_pair:
            self.view.set_slices(
                [],
                "Two scans of a plot: these slices fit one stem. Each tree's slices "
                "from every scan are in the Plot window (select a tree).",
            )
            return
        T, what = _slice_pose(s)
        if T is None or not s.has_scans:
            self.view.set_slices(
                [],
                "No pose to slice yet: match, or make a manual pose.",
            )
            return
        try:
            heights = tuple(
                float(v)
                for v in self.heights.text().replace(";", ",").split(",")
                if v.strip()
            )
            thickness = float(self.thickness.text()) / 100
        except ValueError:
            s.report_error(
                "Stem slices: heights in m separated by commas, thickness in cm."
            )
            return
        # The tree of interest alone once the scans are separated: ground,
        # neighbours and shrubs spoil the circle fits.
        an_t, an_s = s.analysis("target"), s.analysis("source")
        alone = an_t is not None and an_s is not None
        if alone:
            target, source = an_t.tree_xyz, an_s.tree_xyz
        else:
            target, source = s.cloud("target").xyz, s.cloud("source").xyz
        caption = (
            f"Stem slices {what}"
            + (" (tree of interest alone)" if alone else " (all points)")
            + ": amber target, blue source, circles of one radius fitted to each "
            "(good: centres under 15 mm apart)"
        )
        if self._job is not None:  # a newer transform or setting replaces it
            self._job.discard()
            self._job = None
        args = (target, source, T, heights, thickness)
        if len(target) + len(source) <= SYNC_POINTS:  # a few ms: at once
            self.view.set_slices(_slice_pair(*args), caption)
            return
        # Big scans are sliced in a display job: the window never waits for them.
        from amrst_gui import workers

        self._job = workers.run_stage(
            _slice_pair,
            *args,
            name="stem slices",
            display=True,
            on_result=lambda slices: self._show(slices, caption),
            on_error=lambda exc: self._show([], f"Stem slices failed: {exc}"),
        )

    def _show(self, slices, caption: str) -> None:
        from shiboken6 import isValid

        self._job = None
        if isValid(self.view):  # the window may have closed while slicing
            self.view.set_slices(slices, caption)

    def _on_result(self, *_args) -> None:
        if self.isVisible():  # a hidden tab slices when shown (showEvent)
            self.refresh()

    def showEvent(self, event) -> None:
        super().showEvent(event)
        self.refresh()


def _slice_pose(session) -> tuple[np.ndarray | None, str]:
    """The pose the slices show and how to name it: a selected row, else Fine's
    result, else the coarse pose the overlay shows (:func:`shown_coarse`)."""
    shown = shown_coarse(session)
    if session.fine is not None and (shown is None or shown[2] != "selected"):
        return session.fine.T_target_source, "after fine registration"
    if shown is None:
        return None, ""
    T, rank, how = shown
    if how == "accepted":
        return T, "after coarse registration"
    return T, f"of candidate #{rank} ({how}, not accepted)"


def _slice_pair(target, source, T, heights, thickness, reporter=None):
    """Stem slices of the target and of the source moved by ``T`` (a worker's job)."""
    from amrst.review.quality import stem_slices

    moved = source @ T[:3, :3].T + T[:3, 3]
    return stem_slices(target, moved, heights, thickness)
