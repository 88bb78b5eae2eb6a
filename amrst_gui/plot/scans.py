"""The Plot window's scans: the list the next run reads, S1 the reference.

Before a run the list can be reordered (**Make reference**), a scan left out
(**Remove**), and where a scan's scanner stood given (**Scanner at…**, for a file
that does not say). Make reference and Remove emit ``reordered``: the plot shown is
no longer of the scans listed.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import TYPE_CHECKING

from PySide6.QtCore import Qt, Signal
from PySide6.QtWidgets import (
    QHBoxLayout,
    QInputDialog,
    QLabel,
    QListWidget,
    QPushButton,
    QVBoxLayout,
    QWidget,
)

from amrst.errors import InvalidInput
from amrst_gui.plot.tables import scan_file_exists, scan_lines, scan_title
from amrst_gui.plot.typed import short_number, typed_numbers

if TYPE_CHECKING:
    from collections.abc import Iterable, Mapping

    from amrst_gui.plot.jobs import PlotOutcome

#: Set after a scan's line in the list when its scanner position is given.
GIVEN_MARK = "; scanner given"

Scanner = tuple[float, float, float]


class ScansPanel(QWidget):
    """The scans listed, their names and the scanner positions given.

    Emits ``said(text, error)`` for the window's status line, and ``reordered``
    when Make reference or Remove changed the list.
    """

    said = Signal(str, bool)
    reordered = Signal()

    def __init__(self, parent: QWidget | None = None) -> None:
        super().__init__(parent)
        self.specs: list[str] = []
        # The names files give their scans (E57 setups), by spec, as last listed.
        self.names: dict[str, str] = {}
        # scan -> where its scanner stood, given by Scanner at… or amrst plot --scanner
        # (the scan file's coordinates); the next run takes it
        self.given_scanners: dict[int, Scanner] = {}
        self._tips: list[str] = []  # each scan's whole line, once a run shows it
        self._busy = self._shown = False
        self.scan_list = QListWidget()
        self.scan_list.setObjectName("plot_scans")
        self.scan_list.setMaximumHeight(96)
        # Names are cut in the middle (scan_title); the whole path is the tooltip.
        self.scan_list.setHorizontalScrollBarPolicy(
            Qt.ScrollBarPolicy.ScrollBarAlwaysOff
        )
        self.scan_list.itemSelectionChanged.connect(self._update_buttons)
        self.reference_button = QPushButton("Make reference")
        self.reference_button.setToolTip(
            "Make the selected scan S1, the reference: the plot's frame and the "
            "positions in trees.csv are its own"
        )
        self.reference_button.clicked.connect(self.make_reference)
        self.remove_button = QPushButton("Remove")
        self.remove_button.setToolTip(
            "Leave the selected scan out of the plot (a setup of another plot, or one "
            "that cannot be read); its file is kept. The shown plot is cleared: Run "
            "plot makes it again of the others"
        )
        self.remove_button.clicked.connect(self.remove_scan)
        self.scanner_button = QPushButton("Scanner at…")
        self.scanner_button.setToolTip(
            "Where the selected scan's scanner stood, X Y Z in the file's own "
            "coordinates, for a file that does not say (a georeferenced LAS): the next "
            "Run checks the tops of the trees it sees from there (amrst plot --scanner)"
        )
        self.scanner_button.clicked.connect(lambda: self.set_scanner())
        head = QHBoxLayout()
        head.addWidget(QLabel("<b>Scans</b> (S1: the reference)"), 1)
        head.addWidget(self.scanner_button)
        head.addWidget(self.reference_button)
        head.addWidget(self.remove_button)
        layout = QVBoxLayout(self)
        layout.setContentsMargins(0, 0, 0, 0)
        layout.addLayout(head)
        layout.addWidget(self.scan_list)
        self._update_buttons()

    def take(self, paths: Iterable[str | os.PathLike[str]]) -> None:
        """List the scans the next run reads (the first is the reference), no
        scanner given."""
        self.specs = [os.path.abspath(p) for p in paths]  # a link keeps its name
        self.given_scanners = {}
        self._tips = []
        self.scan_list.clear()
        for k, spec in enumerate(self.specs):
            title = scan_title(spec, self.names.get(spec, ""), short=True)
            gone = "" if scan_file_exists(spec) else "  (not found)"
            self.scan_list.addItem(f"S{k + 1}  {title}{gone}")
        self._show_given()
        self._update_buttons()

    def name(self, listed: Iterable[tuple[str, str]]) -> None:
        """Keep the names a file gives its scans, (spec, name), for their lines."""
        self.names.update((os.path.abspath(s), name) for s, name in listed if name)

    def show_lines(self, o: PlotOutcome) -> None:
        """Say how the run placed each scan, in its line."""
        lines = scan_lines(o)
        self._tips = [whole for _listed, whole in lines]  # the list cuts them
        for k, (text, _whole) in enumerate(lines):
            item = self.scan_list.item(k)
            if item is not None:
                item.setText(text)
        self._show_given()

    def set_given(self, given: Mapping[int, Scanner]) -> None:
        """Take the scanner positions given for the next run (as the run shown had)."""
        self.given_scanners = dict(given)
        self._show_given()

    def set_state(self, busy: bool, shown: bool) -> None:
        """A job runs (``busy``: nothing changes), a plot of these scans is shown
        (its reference stays; Remove clears it)."""
        self._busy, self._shown = busy, shown
        self._update_buttons()

    def make_reference(self) -> None:
        """Put the selected scan first: the next run's reference (before a run)."""
        k = self.scan_list.currentRow()
        if self._busy or self._shown or not 0 < k < len(self.specs):
            return
        self._reorder([k, *range(k), *range(k + 1, len(self.specs))])
        self.said.emit(f"{Path(self.specs[0]).name} is the reference now (S1).", False)

    def remove_scan(self) -> None:
        """Leave the selected scan out of the plot; two scans at least stay."""
        k = self.scan_list.currentRow()
        if self._busy or not 0 <= k < len(self.specs) or len(self.specs) <= 2:
            return
        gone = self._title(k)
        self._reorder([j for j in range(len(self.specs)) if j != k])
        reference = f" {self._title(0)} is the reference now (S1)." if k == 0 else ""
        self.said.emit(
            f"{gone} is left out: {len(self.specs)} scans.{reference} Run plot "
            "registers and inventories them.",
            False,
        )

    def set_scanner(self, text: str | None = None) -> None:
        """Give where the selected scan's scanner stood, for the next run.

        ``text``: X Y Z (asked when None); blank forgets the position given.
        """
        from amrst.plot.cli import given_scanners

        k = self.scan_list.currentRow()
        if self._busy or not 0 <= k < len(self.specs):
            return
        name = f"S{k + 1}"
        if text is None:
            now = self.given_scanners.get(k)
            text, ok = QInputDialog.getText(
                self,
                f"Scanner of {name}",
                f"Where the scanner of {name} stood: X Y Z in metres, in the file's "
                "own coordinates (blank: not known).",
                text="" if now is None else " ".join(short_number(v) for v in now),
            )
            if not ok:
                return
        parts = typed_numbers(text)
        if not parts:
            self.given_scanners.pop(k, None)
            self._show_given()
            self.said.emit(
                f"The scanner of {name} is not given: its file decides.", False
            )
            return
        if len(parts) != 3 or any("," in p for p in parts):
            self.said.emit(
                f"The scanner of {name}: give X Y Z, three numbers with decimal "
                f"points, separated by spaces (got {text.strip()[:40]!r}).",
                True,
            )
            return
        try:
            (xyz,) = given_scanners([[str(k + 1), *parts]]).values()
        except InvalidInput as exc:
            self.said.emit(str(exc), True)
            return
        self.given_scanners[k] = xyz
        self._show_given()
        self.said.emit(
            f"The scanner of {name} stood at {', '.join(f'{v:.2f}' for v in xyz)} m "
            "(file coordinates): Run plot checks the tops of its trees from there.",
            False,
        )

    def _title(self, k: int) -> str:
        return scan_title(self.specs[k], self.names.get(self.specs[k], ""))

    def _reorder(self, order: list[int]) -> None:
        """List the scans ``order`` names (their indices); a scanner given stays with
        its scan."""
        given = self.given_scanners
        self.take([self.specs[j] for j in order])
        self.set_given({n: given[j] for n, j in enumerate(order) if j in given})
        self.reordered.emit()

    def _show_given(self) -> None:
        """Mark the scans whose scanner position the next run is given."""
        for k in range(self.scan_list.count()):
            item = self.scan_list.item(k)
            text = item.text().split(GIVEN_MARK)[0]
            tip = "\n".join(
                t
                for t in (
                    self._tips[k] if k < len(self._tips) else "",
                    self.specs[k] if k < len(self.specs) else "",
                )
                if t
            )
            if k in self.given_scanners:
                where = ", ".join(f"{v:.2f}" for v in self.given_scanners[k])
                text += GIVEN_MARK
                tip += f"\nScanner given at {where} m, in the file's coordinates"
            item.setText(text)
            item.setToolTip(tip)

    def _update_buttons(self) -> None:
        k, n = self.scan_list.currentRow(), len(self.specs)
        self.reference_button.setEnabled(not self._busy and not self._shown and k > 0)
        self.scanner_button.setEnabled(not self._busy and 0 <= k < n)
        self.remove_button.setEnabled(self.scanner_button.isEnabled() and n > 2)
