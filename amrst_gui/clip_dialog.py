"""Cut a tree out of a plot file: open the plot, click its stem in a top view.

The dialog reads a thinned overview of the plot in a worker (``io.read_overview``),
draws it as a density image seen from above, and takes the stem where the user
clicks. "Clip" cuts the cylinder and writes the tree atomically into ``out_dir``
(``jobs.clip_tree_to``, in the engine process: closing the dialog stops it), then
loads it into the session as the chosen scan.
"""

from __future__ import annotations

import tempfile
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
from PySide6.QtCore import QPointF, Qt, Signal
from PySide6.QtGui import QColor, QImage, QPainter, QPen, QPixmap
from PySide6.QtWidgets import (
    QComboBox,
    QDialog,
    QDoubleSpinBox,
    QFileDialog,
    QFormLayout,
    QHBoxLayout,
    QLabel,
    QPushButton,
    QVBoxLayout,
    QWidget,
)

from amrst_gui import jobs, workers
from amrst_gui.engine_process import in_engine

if TYPE_CHECKING:
    from PySide6.QtGui import QMouseEvent, QPaintEvent

_VIEW_PX = 480


class TopView(QWidget):
    """A plot seen from above (point density); a click picks a stem (world x, y)."""

    picked = Signal(float, float)

    def __init__(self, parent: QWidget | None = None) -> None:
        super().__init__(parent)
        self.setFixedSize(_VIEW_PX, _VIEW_PX)
        self._pixmap: QPixmap | None = None
        self._origin = np.zeros(2)  # world x, y of the image's lower-left corner
        self._cell = 1.0  # metres per pixel
        self.stem: tuple[float, float] | None = None
        self.radius_m = 2.0

    def show_points(self, world_xy: np.ndarray) -> None:
        """Draw the density of (N, 2) world x, y."""
        lo, hi = world_xy.min(axis=0), world_xy.max(axis=0)
        self._cell = float(max(hi - lo) / (_VIEW_PX - 1)) or 1.0
        self._origin = lo
        ij = np.floor((world_xy - lo) / self._cell).astype(int)
        counts = np.zeros((_VIEW_PX, _VIEW_PX))
        np.add.at(counts, (_VIEW_PX - 1 - ij[:, 1], ij[:, 0]), 1)
        grey = (255 * np.log1p(counts) / max(np.log1p(counts).max(), 1e-9)).astype(
            np.uint8
        )
        self._image = np.ascontiguousarray(255 - grey)
        image = QImage(
            self._image.data,
            _VIEW_PX,
            _VIEW_PX,
            _VIEW_PX,
            QImage.Format.Format_Grayscale8,
        )
        self._pixmap = QPixmap.fromImage(image)
        self.update()

    def world_at(self, x_px: float, y_px: float) -> tuple[float, float]:
        """World x, y under a pixel of the view."""
        x = self._origin[0] + (x_px + 0.5) * self._cell
        y = self._origin[1] + (_VIEW_PX - 1 - y_px + 0.5) * self._cell
        return float(x), float(y)

    def pixel_of(self, x: float, y: float) -> QPointF:
        """The view pixel of world x, y."""
        return QPointF(
            (x - self._origin[0]) / self._cell - 0.5,
            _VIEW_PX - 1 - (y - self._origin[1]) / self._cell + 0.5,
        )

    def mousePressEvent(self, event: QMouseEvent) -> None:
        if self._pixmap is None or event.button() != Qt.MouseButton.LeftButton:
            return
        self.stem = self.world_at(event.position().x(), event.position().y())
        self.picked.emit(*self.stem)
        self.update()

    def paintEvent(self, event: QPaintEvent) -> None:
        painter = QPainter(self)
        painter.fillRect(self.rect(), QColor(255, 255, 255))
        if self._pixmap is not None:
            painter.drawPixmap(0, 0, self._pixmap)
        if self.stem is not None:
            painter.setPen(QPen(QColor(220, 40, 40), 2))
            r_px = self.radius_m / self._cell
            painter.drawEllipse(self.pixel_of(*self.stem), r_px, r_px)
        painter.end()


class ClipDialog(QDialog):
    """Open a plot file, click a stem, set the radius: the tree becomes a scan.

    Emits ``clipped(role, path)`` once the tree is written and its loading into
    the session has started.
    """

    clipped = Signal(str, str)
    overview_ready = Signal()

    def __init__(
        self, session: Any, parent: QWidget | None = None, out_dir: Path | None = None
    ) -> None:
        super().__init__(parent)
        self.setWindowTitle("Cut a tree out of a plot file")
        self.session = session
        self.out_dir = out_dir or Path(tempfile.gettempdir()) / "amrst-clips"
        self.plot: Path | None = None
        self._job: workers.StageJob | None = None
        self.view = TopView(self)
        self.file_label = QLabel("No plot file")
        browse = QPushButton("Open plot file…")
        browse.clicked.connect(self._browse)
        self.radius = QDoubleSpinBox(minimum=0.2, maximum=50.0, value=2.0, suffix=" m")
        self.radius.setSingleStep(0.5)
        self.radius.valueChanged.connect(self._radius_changed)
        self.role = QComboBox()
        self.role.addItems(["target", "source"])
        self.stem_label = QLabel("Click a stem in the top view")
        self.status = QLabel("")
        self.status.setWordWrap(True)
        self.clip_button = QPushButton("Clip and load")
        self.clip_button.setEnabled(False)
        self.clip_button.clicked.connect(self.clip)
        self.view.picked.connect(self._picked)

        top = QHBoxLayout()
        top.addWidget(browse)
        top.addWidget(self.file_label, 1)
        form = QFormLayout()
        form.addRow("Stem", self.stem_label)
        form.addRow("Radius", self.radius)
        form.addRow("Load as", self.role)
        layout = QVBoxLayout(self)
        layout.addLayout(top)
        layout.addWidget(self.view)
        layout.addLayout(form)
        layout.addWidget(self.clip_button)
        layout.addWidget(self.status)

    # ------------------------------------------------------------ plot file
    def _browse(self) -> None:
        from amrst import io

        patterns = " ".join(f"*{ext}" for ext in io.supported_extensions())
        path, _ = QFileDialog.getOpenFileName(
            self, "Open a plot file", "", f"Point clouds ({patterns})"
        )
        if path:
            self.open_plot(path)

    def open_plot(self, path: str | Path) -> None:
        """Read a thinned overview of the plot in a worker, then draw it."""
        from amrst import io

        self.plot = Path(path)
        self.file_label.setText(self.plot.name)
        self.status.setText("Reading an overview…")
        self.view.stem = None
        self.clip_button.setEnabled(False)
        if self._job is not None and not self._job.done:
            self._job.discard()  # the file opened before: its picture never shows
        self._job = workers.run_stage(
            io.read_overview,
            self.plot,
            200_000,
            name="overview",
            on_result=self._show_overview,
            on_error=self._failed,
        )

    def _show_overview(self, cloud: Any) -> None:
        self.view.show_points(cloud.world_xyz[:, :2])
        self.status.setText(
            f"{cloud.meta['overview_of']:,} points; click the stem of the tree to cut."
        )
        self.overview_ready.emit()

    # ------------------------------------------------------------ stem, radius
    def _picked(self, x: float, y: float) -> None:
        self.stem_label.setText(f"x {x:.2f}, y {y:.2f}")
        self.clip_button.setEnabled(True)

    def _radius_changed(self, value: float) -> None:
        self.view.radius_m = value
        self.view.update()

    # ------------------------------------------------------------ clip
    def clip(self) -> None:
        """Cut the cylinder and write it in the engine; load it as the chosen scan."""
        from amrst.clip import ClipParams

        if self.plot is None or self.view.stem is None:
            return
        params = ClipParams(stem_xy=self.view.stem, radius_m=self.radius.value())
        x, y = self.view.stem
        out = self.out_dir / f"{self.plot.stem}_tree_{x:.1f}_{y:.1f}.laz"
        self.status.setText("Clipping…")
        self.clip_button.setEnabled(False)
        self._job = workers.run_stage(
            in_engine(jobs.clip_tree_to, what="the clip"),
            self.plot,
            params,
            out,
            name="clip",
            on_progress=lambda _f, message: self.status.setText(message),
            on_result=self._clipped,
            on_error=self._failed,
        )

    def _clipped(self, result: tuple[Path, int]) -> None:
        out, n = result
        role = self.role.currentText()
        self.status.setText(f"{n:,} points written to {out}; loading as {role}.")
        self.clip_button.setEnabled(True)
        self.session.load_scan(role, out)
        self.clipped.emit(role, str(out))

    def _failed(self, exc: BaseException) -> None:
        self.status.setText(str(exc))
        self.clip_button.setEnabled(self.view.stem is not None)

    def done(self, result: int) -> None:
        if self._job is not None and not self._job.done:
            self._job.cancel()
        super().done(result)
