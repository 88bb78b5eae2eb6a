"""The Plot window's links: every pair of scans, and what the next run does with one.

A link is checked in the main window (**Open pair**), accepted at its pose
(**Accept**), placed from point pairs at the next run (**Use pairs…**: a CSV the
Manual pose dock saved) or left out of it (**Leave out**). Opening and accepting are
the window's to do (``open_asked``, ``accept_asked``: they need the main window and
the review); the choices for the next run are this panel's (``hand_pairs``,
``left_out``).
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

from PySide6.QtCore import Signal
from PySide6.QtWidgets import (
    QFileDialog,
    QHBoxLayout,
    QLabel,
    QPushButton,
    QVBoxLayout,
    QWidget,
)

from amrst.errors import AmrstError
from amrst.plot.review import ACCEPTED, REVIEW_JSON
from amrst.review.verdict import NEEDS_REVIEW
from amrst_gui.plot.tables import LINK_COLUMNS, ROW_PX, fill, link_rows, table

if TYPE_CHECKING:
    from collections.abc import Mapping, Set

    from amrst_gui.plot.jobs import LinkLine, PlotOutcome


#: The links table shows at least this many rows, and at most the second on a laptop
#: screen or the third on a screen at least TALL_SCREEN_PX high (more scroll).
LINK_ROWS = (2, 6, 10)
TALL_SCREEN_PX = 1000


def link_rows_shown(links: int, screen_px: int) -> int:
    """Rows the links table shows for ``links`` links on a screen ``screen_px`` high."""
    most = LINK_ROWS[2] if screen_px >= TALL_SCREEN_PX else LINK_ROWS[1]
    return min(max(links, LINK_ROWS[0]), most)


class LinksPanel(QWidget):
    """The links table and the selected link's buttons.

    Emits ``said(text, error)`` for the window's status line.
    """

    said = Signal(str, bool)
    open_asked = Signal()
    accept_asked = Signal()

    def __init__(self, parent: QWidget | None = None) -> None:
        super().__init__(parent)
        self.lines: tuple[LinkLine, ...] = ()  # the links shown, a row each
        self.hand_pairs: dict[tuple[int, int], str] = {}  # link -> pairs CSV
        self.left_out: set[tuple[int, int]] = set()  # links the next run leaves out
        self._busy = False
        self.table = table(LINK_COLUMNS, "plot_links")
        self._fit_rows(0)
        self.table.setToolTip(
            "Every pair of scans: its state, the stems it shares (within 30 cm at the "
            "link's pose; its pose may have come from fewer), the overlap, the "
            "residual (how far the second scan lies from the first one's surfaces at "
            "the link's pose) and what found the pose (stems, or the two-scan "
            "engine). ★: in the spanning tree that places the scans."
        )
        self.table.itemSelectionChanged.connect(self._update_buttons)
        self.open_button = QPushButton("Open pair")
        self.open_button.setToolTip(
            "Show the selected link's two scans at its pose in the main window: check "
            "the overlay, or pick point pairs in the Manual pose dock and save them"
        )
        self.open_button.clicked.connect(self.open_asked)
        self.accept_button = QPushButton("Accept")
        self.accept_button.setToolTip(
            "Accept the selected link at its pose after checking it (Open pair): the "
            f"scans it places read accepted; kept in {REVIEW_JSON} while a run gives "
            "the link the same pose"
        )
        self.accept_button.clicked.connect(self.accept_asked)
        self.pairs_button = QPushButton("Use pairs…")
        self.pairs_button.setToolTip(
            "Place the selected link from a point pairs CSV (first scan's points as "
            "target) at the next run, instead of the automatic match"
        )
        self.pairs_button.clicked.connect(lambda: self.toggle_pairs())
        self.leave_button = QPushButton("Leave out")
        self.leave_button.setToolTip(
            "Leave the selected link out of the next run (one you found wrong): the "
            "plot then joins its scans through the other links"
        )
        self.leave_button.clicked.connect(self.toggle_left_out)
        buttons = QHBoxLayout()
        for button in (
            self.open_button,
            self.accept_button,
            self.pairs_button,
            self.leave_button,
        ):
            buttons.addWidget(button)
        layout = QVBoxLayout(self)
        layout.setContentsMargins(0, 0, 0, 0)
        layout.addWidget(QLabel("<b>Links</b>"))
        layout.addWidget(self.table)
        layout.addLayout(buttons)
        self._update_buttons()

    def selected(self) -> LinkLine | None:
        """The link selected in the table, or None."""
        rows = self.table.selectionModel().selectedRows()
        if not rows or rows[0].row() >= len(self.lines):
            return None
        return self.lines[rows[0].row()]

    def show_links(self, o: PlotOutcome | None) -> None:
        """Show the links of ``o`` (None: none); the selected row stays selected."""
        row = self.table.currentRow()
        self.lines = () if o is None else o.links
        fill(self.table, [] if o is None else link_rows(o))
        self._fit_rows(len(self.lines))
        for r, ln in enumerate(self.lines):
            item = self.table.item(r, 0)
            assert item is not None  # just filled
            item.setToolTip(
                ln.message + ("; in the spanning tree (★)" if ln.in_tree else "")
            )
        if 0 <= row < len(self.lines):
            self.table.selectRow(row)
        self._show_choices()
        self._update_buttons()

    def _fit_rows(self, n: int) -> None:
        """Make the table as tall as its links (:func:`link_rows_shown`): the room a
        plot of few positions does not need goes to the tree list below."""
        screen = self.screen()
        high = screen.availableGeometry().height() if screen is not None else 0
        self.table.setFixedHeight(ROW_PX * link_rows_shown(n, high) + 30)

    def set_choices(
        self, left_out: Set[tuple[int, int]], hand_pairs: Mapping[tuple[int, int], str]
    ) -> None:
        """Take what the next run does with the links (as the run shown did)."""
        self.left_out, self.hand_pairs = set(left_out), dict(hand_pairs)
        self._show_choices()
        self._update_buttons()

    def set_busy(self, busy: bool) -> None:
        """No link is acted on while a job runs."""
        self._busy = busy
        self._update_buttons()

    def toggle_pairs(self, path: str | None = None) -> None:
        """Take a pairs CSV for the selected link (asked when not given), or drop it."""
        from amrst.review.manual import pairs_disagree
        from amrst.review.pairs_file import read_pairs

        line = self.selected()
        if line is None:
            return
        name = f"S{line.target + 1}–S{line.source + 1}"
        if line.key in self.hand_pairs:
            del self.hand_pairs[line.key]
            self._changed(f"Link {name}: the automatic match again at the next run.")
            return
        if path is None:
            path, _ = QFileDialog.getOpenFileName(
                self, f"Point pairs of link {name}", "", "Point pairs (*.csv)"
            )
        if not path:
            return
        try:
            t_pts, s_pts = read_pairs(Path(path))
        except AmrstError as exc:
            self.said.emit(f"Not used: {exc}", True)
            return
        if apart := pairs_disagree(t_pts, s_pts):
            self.said.emit(
                f"Not used: the point pairs of {Path(path).name} {apart}.", True
            )
            return
        self.hand_pairs[line.key] = path
        self.left_out.discard(line.key)
        self._changed(
            f"Link {name} comes from {len(t_pts)} point pairs ({Path(path).name}) at "
            "the next run: Run plot."
        )

    def toggle_left_out(self) -> None:
        """Leave the selected link out of the next runs, or take it in again."""
        line = self.selected()
        if line is None:
            return
        name = f"S{line.target + 1}–S{line.source + 1}"
        if line.key in self.left_out:
            self.left_out.discard(line.key)
            self._changed(f"Link {name} is registered again at the next run.")
        else:
            self.left_out.add(line.key)
            self.hand_pairs.pop(line.key, None)
            self._changed(
                f"Link {name} is left out at the next run: Run plot joins its scans "
                "through the other links."
            )

    def _changed(self, text: str) -> None:
        self.said.emit(text, False)
        self._show_choices()
        self._update_buttons()

    def _show_choices(self) -> None:
        """Name, in the By column, the links the next run places from point pairs
        or leaves out."""
        for r, ln in enumerate(self.lines):
            item = self.table.item(r, len(LINK_COLUMNS) - 1)
            if item is None:
                continue
            path = self.hand_pairs.get(ln.key)
            if path:
                text, tip = "your pairs", f"Placed from {Path(path).name} at each run"
            elif ln.key in self.left_out:
                text, tip = "left out", "Left out at each run (Take in undoes it)"
            else:
                text, tip = ln.origin or "–", ""
            item.setText(text)
            item.setToolTip(tip)

    def _update_buttons(self) -> None:
        line = None if self._busy else self.selected()
        link = None if line is None else line.key
        self.open_button.setEnabled(link is not None)
        accepted = line is not None and line.status == ACCEPTED
        self.accept_button.setEnabled(
            accepted
            or (
                line is not None
                and line.status == NEEDS_REVIEW
                and line.T_world is not None
            )
        )
        self.accept_button.setText("Undo accept" if accepted else "Accept")
        self.pairs_button.setEnabled(link is not None)
        self.pairs_button.setText(
            "Drop pairs" if link in self.hand_pairs else "Use pairs…"
        )
        self.leave_button.setEnabled(link is not None)
        self.leave_button.setText("Take in" if link in self.left_out else "Leave out")
