"""The Plot window's plot area: the radius of a fixed-radius plot and its centre."""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

from PySide6.QtCore import Signal
from PySide6.QtWidgets import (
    QDoubleSpinBox,
    QHBoxLayout,
    QLabel,
    QLineEdit,
    QPushButton,
    QWidget,
)

from amrst.errors import InvalidInput
from amrst.plot.stand import MAX_RADIUS_M, PlotArea
from amrst_gui.plot.typed import short_number, typed_numbers

if TYPE_CHECKING:
    from collections.abc import Sequence


class AreaRow(QWidget):
    """Plot radius and centre, typed, or the centre clicked on the stem map.

    Emits ``edited`` when the radius is set or a centre typed or clicked (the window
    applies it to the plot shown, and the next run takes it), and ``picking(on)``
    when the centre is to be clicked on the map, or no longer.
    """

    edited = Signal()
    picking = Signal(bool)

    def __init__(self, parent: QWidget | None = None) -> None:
        super().__init__(parent)
        self._busy = False
        self.radius_spin = QDoubleSpinBox()
        self.radius_spin.setRange(0.0, MAX_RADIUS_M)
        self.radius_spin.setDecimals(2)  # 5.64, 11.28, 12.62, 17.84 m plots
        self.radius_spin.setSuffix(" m")
        self.radius_spin.setSpecialValueText("no radius")
        self.radius_spin.setKeyboardTracking(False)  # applied once the value is typed
        self.radius_spin.setToolTip(
            "A fixed-radius plot: the stand figures count the trees within this "
            "distance of the plot centre, per hectare. It applies to the plot shown "
            "at once (plot.json, trees.csv) and to the next Run."
        )
        self.centre_edit = QLineEdit()
        self.centre_edit.setPlaceholderText("x y (blank: scanner S1)")
        self.centre_edit.setToolTip(
            "The plot centre, x and y in the reference scan's coordinates as trees.csv "
            "gives positions (world coordinates for a georeferenced scan); blank: "
            "where the reference's scanner stood (as an E57 or PTX file says, else "
            "the file's origin). Enter applies it."
        )
        self.centre_button = QPushButton("On map")
        self.centre_button.setCheckable(True)
        self.centre_button.setToolTip("Click the plot centre on the stem map")
        self.centre_button.toggled.connect(self.picking)
        self.radius_spin.valueChanged.connect(self._enable_centre)
        self.radius_spin.valueChanged.connect(self.edited)
        self.centre_edit.editingFinished.connect(self.edited)
        self._enable_centre()
        row = QHBoxLayout(self)
        row.setContentsMargins(0, 0, 0, 0)
        row.addWidget(QLabel("Plot radius"))
        row.addWidget(self.radius_spin)
        row.addWidget(QLabel("centre"))
        row.addWidget(self.centre_edit, 1)
        row.addWidget(self.centre_button)

    @property
    def picking_centre(self) -> bool:
        """Whether the next click on the map gives the centre."""
        return self.centre_button.isChecked()

    def stop_picking(self) -> None:
        self.centre_button.setChecked(False)

    def set_busy(self, busy: bool) -> None:
        """Lock the fields while a job runs: it ends by showing its plot's area."""
        self._busy = busy
        self.radius_spin.setEnabled(not busy)
        self._enable_centre()

    def show_area(self, area: PlotArea | None) -> None:
        """Show ``area`` (None: no radius) without applying it: it is the plot's own,
        or none for another plot."""
        centre = (0.0, 0.0) if area is None else area.centre_xy
        for widget in (self.radius_spin, self.centre_edit):
            widget.blockSignals(True)
        self.radius_spin.setValue(0.0 if area is None else area.radius_m)
        self.centre_edit.setText(
            "" if centre == (0.0, 0.0) else " ".join(short_number(v) for v in centre)
        )
        for widget in (self.radius_spin, self.centre_edit):
            widget.blockSignals(False)
        self._enable_centre()

    def set_centre(self, xy: Sequence[float]) -> None:
        """Take the centre clicked on the map (the file's coordinates) and apply it."""
        self.stop_picking()
        self.centre_edit.setText(" ".join(f"{v:.2f}" for v in xy))
        self.edited.emit()

    def area(self) -> tuple[float, tuple[float, float] | None] | None:
        """The plot radius to run with, and its centre (None: the reference scanner);
        None without a radius.

        Raises InvalidInput when the centre field holds anything but two numbers.
        """
        radius = self.radius_spin.value()
        if radius <= 0:
            return None
        text = self.centre_edit.text().strip().removeprefix("(").removesuffix(")")
        text = text.strip()  # "( 1 2 )"
        if not text:
            return radius, None
        words = typed_numbers(text)
        try:
            x, y = (float(w) for w in words)
        except ValueError:
            x = y = float("nan")
        if not (math.isfinite(x) and math.isfinite(y)):
            raise InvalidInput(
                "the plot centre takes x and y separated by a space, with decimal "
                "points, as trees.csv gives positions; or nothing for the reference "
                "scanner."
            )
        PlotArea((x, y), radius)  # refuses what amrst plot would
        return radius, (x, y)

    def _enable_centre(self) -> None:
        """A centre is given with a radius, and no job running."""
        on = self.radius_spin.value() > 0 and not self._busy
        for widget in (self.centre_edit, self.centre_button):
            widget.setEnabled(on)
        if not on:
            self.stop_picking()
