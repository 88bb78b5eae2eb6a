"""MatchesPanel: the ranked candidates, selection, reject / restore."""

from __future__ import annotations

from PySide6.QtCore import QAbstractTableModel, QItemSelectionModel, QModelIndex, Qt
from PySide6.QtGui import QColor, QFont
from PySide6.QtWidgets import (
    QAbstractItemView,
    QFrame,
    QHBoxLayout,
    QHeaderView,
    QLabel,
    QScrollArea,
    QSizePolicy,
    QTableView,
    QToolButton,
    QVBoxLayout,
    QWidget,
)

from amrst_gui.panels.verdict_style import verdict_style

COLUMNS = (
    "#",
    "Score",
    "From",
    "Supp.",
    "Vol. m³",
    "Edge err.",
    "SVD",
    "Close",
    "Status",
)
CLOSE_COLUMN = COLUMNS.index("Close")
_TIPS = (
    "Rank (1 = best): verified solutions first, then by score; the trunk heading "
    "search's solutions among themselves by their close fit (Close column)",
    "Verification score: share of sampled source points within 4 cm "
    "(coarse.tight_dist_m) of the target under this pose. Good: 45% or more; "
    "under 15% nothing is verified",
    "Where the pose comes from: tetrahedra (matched skeletons), trunk (heading "
    "search about the stem) or manual (your point pairs, nudge or typed transform)",
    "How many tetrahedron matches agree with this solution",
    "Volume of the tetrahedron (m³); larger ones pin the pose down better",
    "Largest relative difference between corresponding edges",
    "SVD residual: RMS distance of the four vertex pairs after the fit. Good: a few cm",
    "Trunk heading search only: share of sampled source points within "
    "trunk.score_dist_m (1.5 cm by default) of the target after fine registration; "
    "it ranks the headings, as a wrong heading can still score well at 4 cm",
    "'coarse' = used for the coarse solution (best one not rejected)",
)


_ROOT = QModelIndex()
_ORIGIN = {"tetrahedra": "tetra", "trunk": "trunk", "manual": "manual"}


# Rows the table always shows, whatever the header above it says.
MIN_ROWS = 4
_ROW_PX = 22
# The verdict above the table scrolls beyond this height instead of pushing it out.
_HEADER_MAX_PX = 96
# Squeezed, the verdict keeps two lines and the explanation one (both scroll).
_HEADER_MIN_PX = 36
_EXPLANATION_MIN_PX = 20


def rank_reason(cand) -> str:
    """Why a candidate stands where it does in the list, in one sentence."""
    from amrst.stages.candidates import MIN_VERIFIED_SCORE

    origin = str(cand.origin)
    if origin == "manual":
        return "your own pose: manual poses come first, judged by what they show."
    if origin == "stems":
        return (
            "a plot link's pose from the stems both scans share, verified by its "
            "score or, where far-apart scans share little surface, held by four or "
            "more stems (the verdict says which)."
        )
    if origin == "trunk":
        return (
            f"a trunk heading, ranked among the headings by its close fit "
            f"({_num(cand.precise_score, '{:.0%}')} within the tight 1.5 cm, the "
            "Close column), not by Score: after fine registration even a wrong "
            "heading lands some points within 4 cm, so Score says little here."
        )
    if cand.polished and cand.score >= MIN_VERIFIED_SCORE:
        return (
            f"verified: polished and scoring {cand.score:.0%} "
            f"(at least {MIN_VERIFIED_SCORE:.0%}); verified solutions come first."
        )
    if cand.polished:
        return (
            f"polished but not verified (score under {MIN_VERIFIED_SCORE:.0%}): "
            "ranked by its score after the verified ones."
        )
    return "not polished (raw score only): ranked after the polished ones."


def _num(value: float, fmt: str, missing: str = "—") -> str:
    """A number for the table, or ``missing`` for a trunk-search solution (NaN)."""
    return missing if value != value else fmt.format(value)


class CandidateModel(QAbstractTableModel):
    """Table model over ``session.matches`` and ``session.rejected`` (read-only)."""

    def __init__(self, session, parent=None) -> None:
        super().__init__(parent)
        self.session = session
        self.rows: tuple = ()
        # Per row: its cells' texts and its status, made once per reload or review.
        # Qt asks data() for every role of every cell at each repaint and column
        # fit, and the status asks the session for the coarse choice: computed
        # each time, that was GUI-thread work at every new match list.
        self._cells: dict[int, tuple[tuple[str, ...], str]] = {}

    def reload(self) -> None:
        self.beginResetModel()
        self.rows = self.session.matches
        self._cells = {}
        self.endResetModel()

    def review_changed(self) -> None:
        self._cells = {}
        if self.rows:
            self.dataChanged.emit(
                self.index(0, 0), self.index(len(self.rows) - 1, len(COLUMNS) - 1)
            )

    def rowCount(self, parent=_ROOT) -> int:
        return 0 if parent.isValid() else len(self.rows)

    def columnCount(self, parent=_ROOT) -> int:
        return 0 if parent.isValid() else len(COLUMNS)

    def headerData(self, section, orientation, role=Qt.ItemDataRole.DisplayRole):
        if orientation == Qt.Orientation.Horizontal:
            if role == Qt.ItemDataRole.DisplayRole:
                return COLUMNS[section]
            if role == Qt.ItemDataRole.ToolTipRole:
                return _TIPS[section]
        return None

    def status(self, cand) -> str:
        if cand.id in self.session.rejected:
            return "rejected"
        coarse = self.session.coarse
        if (
            coarse is not None
            and coarse.candidate is not None
            and coarse.candidate.id == cand.id
        ):
            return "◀ coarse"
        return ""

    def _row(self, row: int) -> tuple[tuple[str, ...], str]:
        hit = self._cells.get(row)
        if hit is None:
            cand = self.rows[row]
            status = self.status(cand)
            texts = (
                str(cand.rank),
                f"{cand.score:.0%}",
                _ORIGIN.get(str(cand.origin), str(cand.origin)),
                str(cand.support) if cand.origin != "manual" else "—",
                _num(cand.volume_m3, "{:.2f}"),
                _num(cand.edge_error, "{:.1%}"),
                _num(cand.svd_residual_m * 100, "{:.1f} cm"),
                _num(getattr(cand, "precise_score", float("nan")), "{:.1%}"),
                status,
            )
            hit = self._cells[row] = (texts, status)
        return hit

    def data(self, index, role=Qt.ItemDataRole.DisplayRole):
        if not index.isValid():
            return None
        cand = self.rows[index.row()]
        col = index.column()
        if role == Qt.ItemDataRole.DisplayRole:
            return self._row(index.row())[0][col]
        if role == Qt.ItemDataRole.ToolTipRole:
            return str(cand.explanation)
        if role == Qt.ItemDataRole.TextAlignmentRole and col < len(COLUMNS) - 1:
            return int(Qt.AlignmentFlag.AlignRight | Qt.AlignmentFlag.AlignVCenter)
        status = self._row(index.row())[1]
        if role == Qt.ItemDataRole.ForegroundRole and status == "rejected":
            return QColor("#999999")
        if role == Qt.ItemDataRole.FontRole and status:
            font = QFont()
            font.setStrikeOut(status == "rejected")
            font.setBold(status.endswith("coarse"))
            return font
        if role == Qt.ItemDataRole.UserRole:
            return int(cand.id)
        return None


def _text_box(label: QLabel, min_px: int, max_px: int) -> QScrollArea:
    """A wrapped text that scrolls past ``max_px`` and keeps ``min_px`` (a wrapped
    label's own height depends on its width, which a dock's layout does not ask:
    squeezed, it drew over the table and its buttons)."""
    box = QScrollArea()
    box.setWidget(label)
    box.setWidgetResizable(True)
    box.setFrameShape(QFrame.Shape.NoFrame)
    box.setMinimumHeight(min_px)
    box.setMaximumHeight(max_px)
    box.setHorizontalScrollBarPolicy(Qt.ScrollBarPolicy.ScrollBarAlwaysOff)
    return box


class MatchesPanel(QWidget):
    """Ranked candidates; selecting a row shows that match in both views.

    Listens to ``matches_changed``, ``review_changed``, ``selection_changed``
    (and the upstream result signals, which clear the table); calls
    ``session.select_match``; the Reject / Restore buttons trigger the window's
    actions (keys Delete and R while this dock has focus).
    """

    def __init__(self, session, reject_action, restore_action, parent=None) -> None:
        super().__init__(parent)
        self.setObjectName("matches_panel")
        self.setMinimumWidth(240)
        self.session = session
        self.model = CandidateModel(session, self)
        self.table = QTableView()
        self.table.setModel(self.model)
        self.table.setSelectionBehavior(QAbstractItemView.SelectionBehavior.SelectRows)
        self.table.setSelectionMode(QAbstractItemView.SelectionMode.SingleSelection)
        self.table.verticalHeader().hide()
        self.table.verticalHeader().setDefaultSectionSize(22)
        self.table.horizontalHeader().setMinimumSectionSize(24)
        self.table.horizontalHeader().setSectionResizeMode(
            QHeaderView.ResizeMode.ResizeToContents
        )
        # Fit the columns to the first rows only: measuring every row (Qt's default:
        # 1000) calls the model's data() thousands of times on the GUI thread at
        # every new match list; the best-ranked rows' texts are as wide as the
        # others' (the same formats).
        self.table.horizontalHeader().setResizeContentsPrecision(12)
        self.table.horizontalHeader().setStretchLastSection(True)
        # Status right after the rank: never cut off at the dock's right edge.
        self.table.horizontalHeader().moveSection(len(COLUMNS) - 1, 1)
        self.table.setMinimumHeight(
            self.table.horizontalHeader().sizeHint().height()
            + MIN_ROWS * _ROW_PX
            + 2 * self.table.frameWidth()
            + 18  # a horizontal scroll bar
        )
        self.table.selectionModel().currentRowChanged.connect(
            self._on_current_row_changed
        )
        self.coarse_label = QLabel("No matches yet: run Match (Ctrl+3).")
        self.coarse_label.setWordWrap(True)
        self.explanation = QLabel("")
        self.explanation.setWordWrap(True)
        self.explanation.setStyleSheet("color: #505050;")
        buttons = QHBoxLayout()
        self.reject_button, self.restore_button = QToolButton(), QToolButton()
        for button, action in (
            (self.reject_button, reject_action),
            (self.restore_button, restore_action),
        ):
            button.setDefaultAction(action)
            button.setToolButtonStyle(Qt.ToolButtonStyle.ToolButtonTextOnly)
            buttons.addWidget(button)
            self.addAction(action)  # its shortcut works while this panel has focus
        buttons.addStretch(1)
        layout = QVBoxLayout(self)
        layout.setContentsMargins(2, 2, 2, 2)
        header = _text_box(self.coarse_label, _HEADER_MIN_PX, _HEADER_MAX_PX)
        header.setObjectName("matches_header")
        self.header = header
        layout.addWidget(header)
        layout.addWidget(self.table, 3)
        layout.addLayout(buttons)
        box = _text_box(self.explanation, _EXPLANATION_MIN_PX, _HEADER_MAX_PX)
        # The table first: the explanation takes a quarter of the room left over.
        box.setSizePolicy(QSizePolicy.Policy.Preferred, QSizePolicy.Policy.Ignored)
        box.hide()
        self.explanation_box = box
        layout.addWidget(box, 1)
        session.matches_changed.connect(self._on_matches_changed)
        session.review_changed.connect(self._on_review_changed)
        session.selection_changed.connect(self._on_selection_changed)
        # The verdict's next step changes once a result exists.
        session.coarse_accepted.connect(lambda _c: self._show_coarse())
        session.fine_finished.connect(lambda _f: self._show_coarse())
        for name in (
            "scan_loaded",
            "scans_swapped",
            "separation_finished",
            "skeletons_finished",
        ):
            getattr(session, name).connect(self._on_matches_changed)
        self._on_matches_changed()

    def _on_matches_changed(self, *_args) -> None:
        self.model.reload()
        # The Close column only means something for trunk-search solutions; hidden
        # otherwise, so Status stays in view at the dock's default width.
        self.table.setColumnHidden(
            CLOSE_COLUMN,
            not any(getattr(c, "origin", "") == "trunk" for c in self.model.rows),
        )
        self._show_coarse()
        self._on_selection_changed(
            self.session.selected_match and self.session.selected_match.id
        )

    def _on_review_changed(self, _rejected) -> None:
        self.model.review_changed()
        self._show_coarse()

    def _on_selection_changed(self, match_id) -> None:
        cand = self.session.selected_match
        self.explanation.setText(
            ""
            if cand is None
            else f"Match #{cand.rank}: {cand.explanation}\n"
            f"Why #{cand.rank}: {rank_reason(cand)}"
        )
        self.explanation_box.setVisible(cand is not None)  # no room for nothing
        row = next((i for i, c in enumerate(self.model.rows) if c.id == match_id), None)
        sel = self.table.selectionModel()
        if row is None:
            sel.clearSelection()
            return
        index = self.model.index(row, 0)
        if sel.currentIndex().row() != row:
            flags = (
                QItemSelectionModel.SelectionFlag.ClearAndSelect
                | QItemSelectionModel.SelectionFlag.Rows
            )
            sel.setCurrentIndex(index, flags)
        self.table.scrollTo(index)

    def _on_current_row_changed(self, current: QModelIndex, _previous) -> None:
        if current.isValid() and current.row() < len(self.model.rows):
            self.session.select_match(self.model.rows[current.row()].id)

    def _show_coarse(self) -> None:
        s = self.session
        if s.match_result is None:
            self.coarse_label.setText("No matches yet: run Match (Ctrl+3).")
            self.coarse_label.setStyleSheet("")
            return
        verdict = s.verdict
        coarse = s.coarse
        lines = []
        if verdict is not None:
            # The next step is shown when there is one to take; "nothing more is
            # needed" stays in the tooltip (the Matches table keeps its rows).
            nxt = "" if verdict.ok else f" <i>Next: {verdict.next_step}</i>"
            lines.append(f"<b>{verdict.headline}</b>: {verdict.reason}{nxt}")
        from amrst.plot.stand import counted

        counts = f"{counted(len(s.matches), 'candidate')}, {len(s.rejected)} rejected."
        if coarse is not None:
            # The accepted solution's own confidence (a stored one's as stored), as
            # the verdict above judges it; the list's while another is the solution.
            accepted = s.accepted_coarse
            if accepted is not None and accepted.candidate.id == coarse.candidate.id:
                coarse = accepted
            lines.append(
                f"Coarse solution: candidate #{coarse.candidate.rank}, confidence "
                f"{coarse.confidence:.0%}; {counts}"
            )
        else:
            lines.append(counts)
        self.coarse_label.setText("<br>".join(lines))
        self.coarse_label.setToolTip(verdict.text() if verdict is not None else "")
        self.coarse_label.setStyleSheet(
            "" if verdict is None else verdict_style(verdict.status)
        )
