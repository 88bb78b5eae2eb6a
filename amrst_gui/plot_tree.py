"""The Plot window's tree view: one tree's figures, its slice at 1.3 m, its mark.

Emits ``mark_chosen(tree id, mark)`` with mark ``ok``, ``check`` or ``""`` (clear).
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np
from PySide6.QtCore import Signal
from PySide6.QtWidgets import (
    QFormLayout,
    QHBoxLayout,
    QLabel,
    QPushButton,
    QVBoxLayout,
    QWidget,
)

from amrst_gui.plot_jobs import SLICE_HEIGHT_M
from amrst_gui.views.stem_map import TreeSliceView, scan_colour

if TYPE_CHECKING:
    from amrst.plot.inventory import Tree
    from amrst_gui.plot_jobs import PlotOutcome

#: The rows of the tree's figures.
FIGURES = (
    "Position",
    "Height",
    "DBH",
    "DBH fit",
    "Lean",
    "Crown",
    "Points",
    "Seen from",
    "Your mark",
)

FIGURE_TIPS = {
    "Position": "The stem base, in the reference scan's frame (world coordinates "
    "when the files carry an offset), as trees.csv lists it",
    "DBH fit": "The DBH circle's fit: the arc of the stem its points cover, their "
    "residual, and the share of slice points off the circle (3DFin's checks)",
    "Seen from": "The scans whose points reach the stem",
}


def _value(value: object, unit: str = "", scale: float = 1.0, digits: int = 2) -> str:
    if isinstance(value, str) or value is None:
        return "–"
    number = float(value) * scale  # type: ignore[arg-type]
    return "–" if not np.isfinite(number) else f"{number:.{digits}f}{unit}"


def figures(tree: Tree, mark: str | None) -> list[tuple[str, str]]:
    """The tree's figures, label and text (world coordinates, as trees.csv)."""
    s = tree.stem
    x, y, z = tree.xyz
    seen = ", ".join(
        f'<span style="color:{scan_colour(k - 1).name()}">S{k}</span>'
        for k in tree.seen_from
    )
    return [
        ("Position", f"x {x:.2f}, y {y:.2f}, z {z:.2f} m"),
        ("Height", f"{_value(s.height_m, ' m')} ({s.height_flag})"),
        ("DBH", f"{_value(s.dbh_m, ' cm', 100, 1)} ({s.dbh_quality})"),
        (
            "DBH fit",
            f"arc {_value(s.arc_deg, '°', digits=0)}, ±"
            f"{_value(s.rmse_m, ' mm', 1000, 1)}, "
            f"{_value(s.outlier_share, ' %', 100, 0)} off",
        ),
        ("Lean", _value(s.lean_deg, "°", digits=1)),
        ("Crown", f"{_value(s.crown_width_m, ' m')} wide"),
        ("Points", f"{s.n_points:,}"),
        ("Seen from", seen or "–"),
        ("Your mark", mark or "not marked"),
    ]


class TreePanel(QWidget):
    """The selected tree: title, figures, the breast-height slice, mark buttons."""

    mark_chosen = Signal(str, str)

    def __init__(self, parent: QWidget | None = None) -> None:
        super().__init__(parent)
        self.setObjectName("tree_panel")
        self.tree_id: str | None = None
        self.title = QLabel("No tree selected")
        self.title.setStyleSheet("font-weight: bold; font-size: 11pt;")
        self.hint = QLabel("Click a tree on the stem map, or a row of the list.")
        self.hint.setWordWrap(True)
        form = QFormLayout()
        form.setContentsMargins(0, 0, 0, 0)
        form.setVerticalSpacing(2)
        self.values: dict[str, QLabel] = {}
        for name in FIGURES:
            value = QLabel("–")
            value.setToolTip(FIGURE_TIPS.get(name, ""))
            value.setObjectName(f"tree_{name.lower().replace(' ', '_')}")
            form.addRow(f"<b>{name}</b>", value)
            self.values[name] = value
        self.slice_view = TreeSliceView(self)
        self.slice_view.setToolTip(
            f"The points around the stem {SLICE_HEIGHT_M:g} m above the ground, "
            "coloured by the scan they came from, and the fitted DBH circle (white). "
            "Good: the points lie on the circle all round; a short arc, a branch or "
            "points off the circle make the DBH doubtful."
        )
        self.buttons = {}
        row = QHBoxLayout()
        for mark, text, tip in (
            ("ok", "Mark ok", "The tree and its figures are right"),
            ("check", "Mark check", "Something is wrong here: look again in the field"),
            ("", "Clear", "Remove your mark"),
        ):
            button = QPushButton(text)
            button.setToolTip(tip)
            button.setEnabled(False)
            button.clicked.connect(lambda _=False, m=mark: self._mark(m))
            row.addWidget(button)
            self.buttons[mark] = button
        layout = QVBoxLayout(self)
        layout.setContentsMargins(6, 4, 6, 4)
        layout.addWidget(self.title)
        layout.addWidget(self.hint)
        layout.addLayout(form)
        layout.addWidget(self.slice_view, 1)
        layout.addLayout(row)

    def show_tree(
        self, outcome: PlotOutcome | None, k: int | None, mark: str | None
    ) -> None:
        """Show tree ``k`` of ``outcome`` (None: no tree)."""
        if outcome is None or k is None:
            self.tree_id = None
            self.title.setText("No tree selected")
            self.hint.show()
            for value in self.values.values():
                value.setText("–")
            self.slice_view.set_slice(None, np.zeros(2), float("nan"), "")
        else:
            tree = outcome.trees[k]
            self.tree_id = tree.tree_id
            self.title.setText(f"Tree {tree.tree_id}")
            self.hint.hide()
            for name, text in figures(tree, mark):
                self.values[name].setText(text)
            n = len(outcome.slices[k].xy)
            self.slice_view.set_slice(
                outcome.slices[k],
                tree.stem.dbh_xy,
                tree.stem.dbh_m / 2,
                f"{n} points at {SLICE_HEIGHT_M:g} m ± 5 cm; circle: the DBH fit",
            )
        for button in self.buttons.values():
            button.setEnabled(self.tree_id is not None)

    def _mark(self, mark: str) -> None:
        if self.tree_id is not None:
            self.mark_chosen.emit(self.tree_id, mark)
