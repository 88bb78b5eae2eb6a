"""The Plot window's two tables: the links between the scans, and the trees."""

from __future__ import annotations

from typing import TYPE_CHECKING

from PySide6.QtCore import Qt
from PySide6.QtGui import QBrush, QColor
from PySide6.QtWidgets import (
    QAbstractItemView,
    QHeaderView,
    QTableWidget,
    QTableWidgetItem,
)

from amrst.plot.review import ACCEPTED
from amrst.review.verdict import NEEDS_REVIEW

if TYPE_CHECKING:
    from collections.abc import Sequence

    from amrst.plot.review import PlotReview
    from amrst_gui.plot_jobs import PlotOutcome

TREE_COLUMNS = ("Tree", "DBH cm", "DBH quality", "Height m", "Height flag", "Mark")
LINK_COLUMNS = ("Link", "State", "Stems", "Overlap", "RMSE", "By")
ROW_PX = 20  # table rows: six links and a dozen trees show on a laptop screen


def table(columns: tuple[str, ...], name: str) -> QTableWidget:
    table = QTableWidget(0, len(columns))
    table.setObjectName(name)
    table.setHorizontalHeaderLabels(list(columns))
    table.verticalHeader().setVisible(False)
    table.verticalHeader().setDefaultSectionSize(ROW_PX)
    table.setEditTriggers(QAbstractItemView.EditTrigger.NoEditTriggers)
    table.setSelectionBehavior(QAbstractItemView.SelectionBehavior.SelectRows)
    table.setSelectionMode(QAbstractItemView.SelectionMode.SingleSelection)
    table.horizontalHeader().setSectionResizeMode(
        QHeaderView.ResizeMode.ResizeToContents
    )
    table.horizontalHeader().setStretchLastSection(True)
    # The columns fit the side column; a scroll bar would take a row's height.
    table.setHorizontalScrollBarPolicy(Qt.ScrollBarPolicy.ScrollBarAlwaysOff)
    return table


def fill(table: QTableWidget, rows: Sequence[Sequence[str]]) -> None:
    table.setRowCount(len(rows))
    for r, row in enumerate(rows):
        for c, text in enumerate(row):
            table.setItem(r, c, QTableWidgetItem(text))


def number(value: float, fmt: str) -> str:
    return "–" if value != value else format(value, fmt)  # NaN


def scan_lines(o: PlotOutcome) -> list[str]:
    """One line per scan: its file, where it stood, how many stems it shows."""
    from pathlib import Path

    lines = []
    for k, scan in enumerate(o.scans):
        where = (
            "reference"
            if k == 0
            else "not placed"
            if not scan.placed
            else "placed (the file does not say where its scanner stood)"
            if scan.xy is None
            else f"at {scan.xy[0]:.1f}, {scan.xy[1]:.1f} m"
        )
        # Only a placed scan the registration was not sure of says its state.
        unsure = scan.placed and scan.status in (NEEDS_REVIEW, ACCEPTED)
        state = f", {scan.status}" if unsure else ""
        gone = "" if scan_file_exists(scan.label) else " (file missing)"
        lines.append(
            f"S{k + 1}  {Path(scan.label).name}{gone}: {where}, {scan.stems} stems"
            f"{state}"
        )
    return lines


def scan_file_exists(label: str) -> bool:
    """Whether the file of a scan label (``FILE`` or ``FILE#k``) is where it says."""
    from amrst.errors import InvalidInput
    from amrst.io.scans import split_spec

    try:
        return split_spec(label)[0].is_file()
    except InvalidInput:
        return False


def link_rows(o: PlotOutcome) -> list[tuple[str, ...]]:
    """One row per link: scans (★ in the spanning tree), state ("(loop)": a loop of
    links confirms it), stems, overlap, NN-RMSE in the overlap, and what found the
    pose."""
    return [
        (
            f"S{ln.target + 1}–S{ln.source + 1}" + (" ★" if ln.in_tree else ""),
            ln.status + (" (loop)" if ln.confirmed else ""),
            str(ln.shared),
            number(ln.overlap * 100, ".0f") + " %",
            number(ln.rmse_m * 100, ".1f") + " cm",
            ln.origin or "–",
        )
        for ln in o.links
    ]


def tree_rows(o: PlotOutcome, review: PlotReview) -> list[tuple[str, ...]]:
    """One row per tree: id, DBH, its quality, height, its flag, the mark.

    A DBH the technician measured shows as theirs (quality ``yours``).
    """
    rows: list[tuple[str, ...]] = []
    for t in o.trees:
        hand = review.dbh.get(t.tree_id)
        dbh, quality = (
            (t.stem.dbh_m, t.stem.dbh_quality)
            if hand is None
            else (hand.dbh_m, "yours")
        )
        rows.append(
            (
                t.tree_id,
                number(dbh * 100, ".1f"),
                quality,
                number(t.stem.height_m, ".1f"),
                t.stem.height_flag,
                review.marks.get(t.tree_id, ""),
            )
        )
    return rows


def grey_outside(table: QTableWidget, o: PlotOutcome) -> None:
    """Grey the rows of the trees outside the fixed-radius plot, and say why."""
    if o.area is None:
        return
    grey = QBrush(QColor(140, 140, 140))
    tip = (
        f"Its stem base lies outside the plot's {o.area.radius_m:g} m radius: "
        "listed, but not in the stand figures (trees.csv in_plot no)"
    )
    for r, t in enumerate(o.trees):
        if o.area.holds(t.row()):  # as trees.csv's in_plot says
            continue
        for c in range(table.columnCount()):
            item = table.item(r, c)
            if item is not None:
                item.setForeground(grey)
                item.setToolTip(tip)
