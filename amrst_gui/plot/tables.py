"""The Plot window's two tables: the links between the scans, and the trees."""

from __future__ import annotations

import math
from pathlib import Path
from typing import TYPE_CHECKING

from PySide6.QtCore import Qt
from PySide6.QtGui import QBrush, QColor
from PySide6.QtWidgets import (
    QAbstractItemView,
    QHeaderView,
    QTableWidget,
    QTableWidgetItem,
)

from amrst.plot.flags import height_words
from amrst.plot.review import ACCEPTED
from amrst.review.verdict import NEEDS_REVIEW, TEXT_RGB

if TYPE_CHECKING:
    from collections.abc import Sequence

    from amrst.plot.review import PlotReview
    from amrst_gui.plot.jobs import PlotOutcome

# Two-line headings: one line each would push the Mark column out of the side column
# at 1366 px.
TREE_COLUMNS = ("Tree", "DBH\ncm", "DBH\nquality", "Height\nm", "Height\nflag", "Mark")
LINK_COLUMNS = ("Link", "State", "Stems", "Overlap", "Residual", "By")
ROW_PX = 20  # table rows: six links and a dozen trees show on a laptop screen
TREE_ROLE = Qt.ItemDataRole.UserRole  # a tree row's index into the outcome's trees
SORT_ROLE = Qt.ItemDataRole.UserRole + 1  # what a cell sorts by


#: Between a number and its unit: a line wraps, never between them.
NBSP = "\u00a0"


def table(columns: tuple[str, ...], name: str) -> QTableWidget:
    table = QTableWidget(0, len(columns))
    table.setObjectName(name)
    table.setHorizontalHeaderLabels(list(columns))
    table.verticalHeader().setVisible(False)
    table.verticalHeader().setDefaultSectionSize(ROW_PX)
    table.setEditTriggers(QAbstractItemView.EditTrigger.NoEditTriggers)
    table.setSelectionBehavior(QAbstractItemView.SelectionBehavior.SelectRows)
    table.setSelectionMode(QAbstractItemView.SelectionMode.SingleSelection)
    # Tab goes on to the buttons, the arrows move within: Tab from cell to cell
    # would hold the keyboard in the table for good.
    table.setTabKeyNavigation(False)
    table.horizontalHeader().setSectionResizeMode(
        QHeaderView.ResizeMode.ResizeToContents
    )
    # The last column takes the width left (its text elided if need be): the others
    # fit the side column at 1366 px; should they not (a large font), a scroll bar
    # reaches them.
    table.horizontalHeader().setSectionResizeMode(
        len(columns) - 1, QHeaderView.ResizeMode.Stretch
    )
    return table


def fill(table: QTableWidget, rows: Sequence[Sequence[str]]) -> None:
    table.setRowCount(len(rows))
    for r, row in enumerate(rows):
        for c, text in enumerate(row):
            table.setItem(r, c, QTableWidgetItem(text))


def number(value: float, fmt: str) -> str:
    return "–" if value != value else format(value, fmt)  # NaN


#: A file name longer than this loses its middle in the scan list.
LIST_NAME_CHARS = 36


def scan_title(spec: str, name: str, *, short: bool = False) -> str:
    """A scan as the window lists it: its file (and ``#k``), then its name if any.

    ``short`` cuts a long file name in the middle: scans of one plot often share a
    long prefix and differ at the end.
    """
    file = Path(spec).name
    if short and len(file) > LIST_NAME_CHARS:
        keep = LIST_NAME_CHARS - 1
        file = f"{file[: keep // 2]}\u2026{file[-(keep - keep // 2) :]}"
    return f"{file} ({name})" if name else file


def scan_lines(o: PlotOutcome) -> list[tuple[str, str]]:
    """One line per scan: its file, where it stood, its stems and residual.

    Each as the list shows it (a long file name cut in the middle,
    :func:`scan_title`) and whole.
    """

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
        residual = (
            f", residual {scan.residual_m * 100:.1f}{NBSP}cm"
            if math.isfinite(scan.residual_m)
            else ""
        )
        rest = f"{gone}: {where}, {scan.stems} stems{residual}{state}"
        listed, whole = (
            f"S{k + 1}  {scan_title(scan.label, scan.name, short=cut)}{rest}"
            for cut in (True, False)
        )
        lines.append((listed, whole))
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
    links confirms it), stems, overlap, the residual, and what found the pose."""
    return [
        (
            f"S{ln.target + 1}–S{ln.source + 1}" + (" ★" if ln.in_tree else ""),
            ln.status + (" (loop)" if ln.confirmed else ""),
            str(ln.shared),
            number(ln.overlap * 100, ".0f") + " %",
            number(ln.residual_m * 100, ".1f") + " cm",
            ln.origin or "–",
        )
        for ln in o.links
    ]


def tree_rows(
    o: PlotOutcome, review: PlotReview
) -> list[tuple[tuple[str, object], ...]]:
    """One row per tree: id, DBH, its quality, height, its flag, the mark; each cell
    its text and the key it sorts by (the tree's order, numbers; none at the end).

    A DBH the technician measured shows as theirs (quality ``yours``).
    """
    rows: list[tuple[tuple[str, object], ...]] = []
    for k, t in enumerate(o.trees):
        hand = review.dbh.get(t.tree_id)
        dbh, quality = (
            (t.stem.dbh_m, t.stem.dbh_quality)
            if hand is None
            else (hand.dbh_m, "yours")
        )
        mark = review.marks.get(t.tree_id, "")
        rows.append(
            (
                (t.tree_id, k),
                (number(dbh * 100, ".1f"), _last_if_nan(dbh)),
                (quality, quality),
                (
                    height_words(t.stem.height_m, t.stem.height_seen_m),
                    _last_if_nan(t.stem.seen_to_m),  # out of range: by how high seen
                ),
                (t.stem.height_flag, t.stem.height_flag),
                (mark, mark or "~"),  # unmarked after the marks
            )
        )
    return rows


def _last_if_nan(value: float) -> float:
    return float("inf") if value != value else float(value)


class _SortItem(QTableWidgetItem):
    """A cell that sorts by its key (``SORT_ROLE``), not its text; a number missing
    (an infinite key) ends the list whichever way it is sorted."""

    def __lt__(self, other: QTableWidgetItem) -> bool:
        a, b = self.data(SORT_ROLE), other.data(SORT_ROLE)
        if type(a) is type(b) and a is not None:
            table = self.tableWidget()
            descending = (
                table is not None
                and table.horizontalHeader().sortIndicatorOrder()
                == Qt.SortOrder.DescendingOrder
            )
            if descending and isinstance(a, float) and math.inf in (a, b):
                return bool(a > b)  # Qt puts the greater first: the missing one last
            return bool(a < b)
        return super().__lt__(other)


def fill_trees(table: QTableWidget, o: PlotOutcome, review: PlotReview) -> None:
    """Fill the tree table, in the order the technician sorted it (by clicking a
    heading), greying the trees outside the fixed-radius plot."""
    table.setSortingEnabled(False)  # else each cell set sorts the rows again
    rows = tree_rows(o, review)
    table.setRowCount(len(rows))
    for k, row in enumerate(rows):
        for c, (text, key) in enumerate(row):
            item = _SortItem(text)
            item.setData(SORT_ROLE, key)
            item.setData(TREE_ROLE, k)
            table.setItem(k, c, item)
    _grey_outside(table, o)
    _flag_unsure(table, o)
    table.setSortingEnabled(True)  # sorts by the heading chosen, the tree order first


def tree_at_row(table: QTableWidget, row: int) -> int | None:
    """The tree (index into the outcome's trees) shown in ``row``."""
    item = table.item(row, 0)
    k = None if item is None else item.data(TREE_ROLE)
    return k if isinstance(k, int) else None


def row_of_tree(table: QTableWidget, k: int) -> int:
    """The row showing tree ``k`` (-1: none)."""
    return next((r for r in range(table.rowCount()) if tree_at_row(table, r) == k), -1)


def _flag_unsure(table: QTableWidget, o: PlotOutcome) -> None:
    """Colour the id of each tree seen from a scan that needs review, and say why."""
    unsure = o.unsure
    for r, t in enumerate(o.trees):  # filled in tree order, sorted after
        doubt = [k for k in t.seen_from if k in unsure]
        item = table.item(r, 0)
        if not doubt or item is None:
            continue
        item.setForeground(QBrush(QColor(TEXT_RGB[NEEDS_REVIEW])))
        scans = ", ".join(f"S{k}" for k in doubt)
        tip = (
            f"Seen from {scans}, which {'needs' if len(doubt) == 1 else 'need'} "
            "review: its figures rest on a pose nobody confirmed yet "
            "(trees.csv scans_to_check)"
        )
        outside = item.toolTip()  # set by _grey_outside
        item.setToolTip(f"{tip}. {outside}" if outside else tip)


def _grey_outside(table: QTableWidget, o: PlotOutcome) -> None:
    """Grey the rows of the trees outside the fixed-radius plot, and say why."""
    if o.area is None:
        return
    grey = QBrush(QColor(140, 140, 140))
    tip = (
        f"Its stem base lies outside the plot's {o.area.radius_m:g} m radius: "
        "listed, but not in the stand figures (trees.csv in_plot no)"
    )
    for r, t in enumerate(o.trees):  # filled in tree order, sorted after
        if o.area.holds(t.row()):  # as trees.csv's in_plot says
            continue
        for c in range(table.columnCount()):
            item = table.item(r, c)
            if item is not None:
                item.setForeground(grey)
                item.setToolTip(tip)
