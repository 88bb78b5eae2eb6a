"""TreeScansPanel: one campaign tree's scans and links, below the Campaign dock's table.

The scans list names each scan, marks the reference and says how each other scan
reached it (the path through the links, or "not reached"); the links list gives each
link's state, score, confidence and NN-RMSE, and whether the spanning tree uses it.
Selecting a link (or a scan: its link to the reference) emits
``link_selected(target, source)``, and the window shows those two scans with the
stored pose between them. Everything comes from
:class:`amrst.campaign.stored.StoredTree`; nothing is computed here.
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

from PySide6.QtCore import QSize, Signal
from PySide6.QtGui import QBrush, QColor
from PySide6.QtWidgets import (
    QAbstractItemView,
    QHeaderView,
    QLabel,
    QTableWidget,
    QTableWidgetItem,
    QVBoxLayout,
    QWidget,
)

from amrst.review.verdict import TEXT_RGB

if TYPE_CHECKING:
    from amrst.campaign.manifest import TreeEntry
    from amrst.campaign.stored import StoredTree

SCAN_COLUMNS = ("Scan", "File", "Reaches the reference")
LINK_COLUMNS = ("Link", "Verdict", "Score", "Conf.", "NN-RMSE cm", "In tree")


def scan_how(stored: StoredTree | None, k: int, reference: int) -> str:
    """How scan ``k`` reaches the reference, in words."""
    if k == reference:
        return "reference"
    if stored is None:
        return "not run"
    path = stored.scans[k].path
    if path is None:
        return "not reached (no verified link)"
    return "via " + " → ".join(map(str, path))


def link_cells(stored: StoredTree) -> list[tuple[str, ...]]:
    """One row of texts per stored link, as the links list shows them."""
    rows: list[tuple[str, ...]] = []
    for link in stored.links:
        rmse = (link.metrics or {}).get("rmse_overlap_m")
        rows.append(
            (
                f"{link.target} ← {link.source}",
                link.status,
                "" if math.isnan(link.score) else f"{link.score:.0%}",
                "" if math.isnan(link.confidence) else f"{link.confidence:.0%}",
                "" if rmse is None else f"{float(rmse) * 100:.1f}",
                "yes" if link.in_tree else "",
            )
        )
    return rows


class _CompactTable(QTableWidget):
    """A table that asks for a few rows only (a tree has 2 to 5 scans), so the dock
    never makes the window taller than a laptop screen."""

    def sizeHint(self) -> QSize:
        rows = 4 * self.verticalHeader().defaultSectionSize()
        return QSize(super().sizeHint().width(), rows)


def _table(columns: tuple[str, ...], name: str) -> QTableWidget:
    table = _CompactTable(0, len(columns))
    table.setObjectName(name)
    table.setHorizontalHeaderLabels(list(columns))
    table.setSelectionBehavior(QAbstractItemView.SelectionBehavior.SelectRows)
    table.setSelectionMode(QAbstractItemView.SelectionMode.SingleSelection)
    table.setEditTriggers(QAbstractItemView.EditTrigger.NoEditTriggers)
    table.verticalHeader().setVisible(False)
    table.verticalHeader().setDefaultSectionSize(table.fontMetrics().height() + 8)
    table.horizontalHeader().setStretchLastSection(True)
    table.horizontalHeader().setSectionResizeMode(
        QHeaderView.ResizeMode.ResizeToContents
    )
    return table


class TreeScansPanel(QWidget):
    """The scans and links of the tree selected in the Campaign dock."""

    link_selected = Signal(int, int)

    def __init__(self, parent: QWidget | None = None) -> None:
        super().__init__(parent)
        self.setObjectName("campaign_tree_scans")
        self.stored: StoredTree | None = None
        self.reference = 0
        self.title = QLabel("Select a tree to see its scans and links.")
        self.title.setWordWrap(True)
        self.scans = _table(SCAN_COLUMNS, "campaign_scans")
        self.links = _table(LINK_COLUMNS, "campaign_links")
        layout = QVBoxLayout(self)
        layout.setContentsMargins(0, 0, 0, 0)
        layout.addWidget(self.title)
        for table in (self.scans, self.links):
            layout.addWidget(table, 1)
        # Shown with the first tree: a hidden panel adds nothing to the window's
        # minimum height while the docks are still stacked, before they are tabbed.
        self.hide()
        self.scans.itemSelectionChanged.connect(self._on_scan)
        self.links.itemSelectionChanged.connect(self._on_link)

    def show_tree(
        self, entry: TreeEntry | None, stored: StoredTree | None, shown: tuple[int, int]
    ) -> None:
        """List one tree's scans (from the manifest) and its stored links, if any."""
        self.stored = stored
        for table in (self.scans, self.links):
            table.blockSignals(True)
            table.clearSelection()
            table.setRowCount(0)
        if entry is None:
            self.title.setText("Select a tree to see its scans and links.")
            self._unblock()
            return
        self.show()
        self.reference = stored.reference if stored is not None else entry.reference
        status = "not run" if stored is None else stored.status
        self.title.setText(
            f"<b>{entry.id}</b>: {len(entry.scans)} scans, {status}; showing "
            f"{shown[1]} onto {shown[0]}"
        )
        self.scans.setRowCount(len(entry.scans))
        for k, spec in enumerate(entry.scans):
            cells: tuple[str, ...] = (
                str(k),
                spec.rsplit("/", 1)[-1],
                scan_how(stored, k, self.reference),
            )
            for j, text in enumerate(cells):
                item = QTableWidgetItem(text)
                item.setToolTip(spec)
                if k == self.reference:
                    font = item.font()
                    font.setBold(True)
                    item.setFont(font)
                self.scans.setItem(k, j, item)
        if stored is not None:
            self.links.setRowCount(len(stored.links))
            for i, cells in enumerate(link_cells(stored)):
                link = stored.links[i]
                for j, text in enumerate(cells):
                    item = QTableWidgetItem(text)
                    item.setToolTip(link.message)
                    if j == 1:
                        colour = TEXT_RGB.get(link.status, "#333333")
                        item.setForeground(QBrush(QColor(colour)))
                    self.links.setItem(i, j, item)
        self.mark_shown(shown)
        self._unblock()

    def mark_shown(self, shown: tuple[int, int]) -> None:
        """Select the row of the link the views show (no signal)."""
        for table in (self.scans, self.links):
            table.blockSignals(True)
            table.clearSelection()
        if self.stored is not None:
            for i, link in enumerate(self.stored.links):
                if {link.target, link.source} == set(shown):
                    self.links.selectRow(i)
        other = shown[1] if shown[0] == self.reference else None
        if other is not None and other < self.scans.rowCount():
            self.scans.selectRow(other)
        self._unblock()

    # ----------------------------------------------------------- plumbing
    def _unblock(self) -> None:
        for table in (self.scans, self.links):
            table.blockSignals(False)

    def _on_scan(self) -> None:
        rows = {i.row() for i in self.scans.selectedIndexes()}
        if len(rows) == 1:
            k = rows.pop()
            if k != self.reference:
                self.link_selected.emit(self.reference, k)

    def _on_link(self) -> None:
        rows = {i.row() for i in self.links.selectedIndexes()}
        if len(rows) == 1 and self.stored is not None:
            link = self.stored.links[rows.pop()]
            self.link_selected.emit(link.target, link.source)
