"""The Plot window's tree list: every tree listed, with Add tree, Report and Export."""

from __future__ import annotations

from typing import TYPE_CHECKING

from PySide6.QtCore import Qt, Signal
from PySide6.QtWidgets import QHBoxLayout, QLabel, QPushButton, QVBoxLayout, QWidget

from amrst_gui.plot.tables import (
    TREE_COLUMNS,
    fill,
    fill_trees,
    row_of_tree,
    table,
    tree_at_row,
)

if TYPE_CHECKING:
    from amrst.plot.review import PlotReview
    from amrst_gui.plot.jobs import PlotOutcome


class TreeList(QWidget):
    """The trees table, sorted as the technician clicks its headings, and its buttons.

    Emits ``chosen(k)`` when a row is selected (``k``: the tree's index into the
    outcome's trees), ``adding(on)`` while a tree is to be clicked on the map, and
    ``report_asked`` and ``export_asked`` for the window to do.
    """

    chosen = Signal(int)
    adding = Signal(bool)
    report_asked = Signal()
    export_asked = Signal()

    def __init__(self, parent: QWidget | None = None) -> None:
        super().__init__(parent)
        self.table = table(TREE_COLUMNS, "plot_trees")
        self.table.horizontalHeader().setSortIndicator(0, Qt.SortOrder.AscendingOrder)
        self.table.setToolTip(
            "Every tree listed: click one to see it, a heading to sort by it. An amber "
            "id: the tree is seen from a scan that needs review. Keys: N / P the "
            "next / previous tree; O mark ok, C mark check, X not a tree, Del clear "
            "the mark."
        )
        self.table.itemSelectionChanged.connect(self._on_row_selected)
        self.export_button = QPushButton("Export inventory…")
        self.export_button.setToolTip(
            "Save the tree list with your marks as a CSV or Excel file elsewhere (the "
            "results folder's trees.csv always holds it too)"
        )
        self.export_button.clicked.connect(self.export_asked)
        self.report_button = QPushButton("Report")
        self.report_button.setToolTip(
            "Write report.html in the results folder (scans, links, the stem map and "
            "the trees, with your review) and open it"
        )
        self.report_button.clicked.connect(self.report_asked)
        self.add_button = QPushButton("Add tree")
        self.add_button.setCheckable(True)
        self.add_button.setToolTip(
            "A tree the list misses: click where its stem stands on the stem map (the "
            "grey shows the vegetation). Run plot measures a tree there and lists it "
            "as H and a number. Click a cross again to take it back; Esc ends adding."
        )
        self.add_button.toggled.connect(self.adding)
        head = QHBoxLayout()
        head.addWidget(QLabel("<b>Trees</b>"), 1)
        head.addWidget(self.add_button)
        head.addWidget(self.report_button)
        head.addWidget(self.export_button)
        layout = QVBoxLayout(self)
        layout.setContentsMargins(0, 0, 0, 0)
        layout.addLayout(head)
        layout.addWidget(self.table, 1)

    @property
    def adding_tree(self) -> bool:
        """Whether the next click on the map adds a tree."""
        return self.add_button.isChecked()

    def stop_adding(self) -> None:
        self.add_button.setChecked(False)

    def set_enabled(self, shown: bool, report_free: bool) -> None:
        """Enable the buttons: a plot shown and no job running, no report being
        written."""
        self.export_button.setEnabled(shown)
        self.add_button.setEnabled(shown)
        if not shown:
            self.stop_adding()
        self.report_button.setEnabled(shown and report_free)

    def show_trees(
        self, o: PlotOutcome | None, review: PlotReview, selected: int | None
    ) -> None:
        """List the trees of ``o`` with the review, tree ``selected`` selected; no
        ``chosen`` is emitted."""
        self.table.blockSignals(True)
        if o is None:
            fill(self.table, [])
        else:
            fill_trees(self.table, o, review)
        if selected is not None:
            self.table.selectRow(row_of_tree(self.table, selected))
        else:
            self.table.clearSelection()
        self.table.blockSignals(False)

    def select(self, k: int, *, quiet: bool = False) -> None:
        """Select tree ``k``'s row, unless it is the current one; ``quiet``: select it
        again in any case, without emitting ``chosen``."""
        row = row_of_tree(self.table, k)
        if self.table.currentRow() == row and not quiet:
            return
        self.table.blockSignals(quiet)
        self.table.selectRow(row)
        self.table.blockSignals(False)

    def stepped(self, step: int) -> int | None:
        """The tree ``step`` rows below the selected one (the first: none selected)."""
        n = self.table.rowCount()
        if not n:
            return None
        row = self.table.currentRow()
        row = min(max(row + step, 0), n - 1) if row >= 0 else 0
        return tree_at_row(self.table, row)

    def _on_row_selected(self) -> None:
        rows = self.table.selectionModel().selectedRows()
        k = tree_at_row(self.table, rows[0].row()) if rows else None
        if k is not None:
            self.chosen.emit(k)
