"""CampaignPanel: the trees of a campaign, their state, and the batch run behind them.

The table lists every tree with its state (not run, queued, running, registered,
needs review, failed, rejected, accepted), those needing a person first, and
can be filtered by text and by "needs a person". The state comes from the campaign
folder (amrst.campaign.table and amrst.campaign.review), so opening a campaign reads
files, never registers. Decisions are written to the folder the moment they are made.
"Run remaining" runs ``amrst.campaign.batch.run_batch`` (the same Dask code as
``amrst batch``) through ``workers.run_stage``; each tree's start and end come back as
signals (:class:`BatchEvents`): a tree reads "running" from the moment a Dask worker
starts it, "queued" while it waits, and its row updates when it finishes.

Below the table, :class:`TreeScansPanel` lists the selected tree's scans and links
(amrst.campaign.stored, read from its result folder).

Emits ``tree_selected(tree id, scan paths with the reference first)`` and
``link_chosen(target path, source path, StoredLinkResult or None)``: the pair to show,
with its stored result (None when the tree has none), for ``Session.load_stored``.
"""

from __future__ import annotations

import logging
from functools import partial
from typing import TYPE_CHECKING

from PySide6.QtCore import (
    QItemSelection,
    QItemSelectionModel,
    QObject,
    Qt,
    QTimer,
    Signal,
)
from PySide6.QtWidgets import (
    QAbstractItemView,
    QCheckBox,
    QGridLayout,
    QHBoxLayout,
    QHeaderView,
    QLabel,
    QLineEdit,
    QMessageBox,
    QPushButton,
    QSizePolicy,
    QSplitter,
    QTableWidget,
    QTableWidgetItem,
    QVBoxLayout,
    QWidget,
)

from amrst.campaign.review import CLEAR
from amrst.campaign.table import OUT_OF_DATE
from amrst.errors import AmrstError
from amrst_gui.panels.campaign_rows import (
    COLUMNS,
    BatchTracker,
    row_cells,
    row_hidden,
)
from amrst_gui.panels.campaign_scans import TreeScansPanel
from amrst_gui.workers import StageJob, run_stage

if TYPE_CHECKING:
    from pathlib import Path

    from amrst.campaign.batch import BatchSummary
    from amrst.campaign.manifest import Campaign
    from amrst.campaign.stored import StoredTree
    from amrst.progress import Reporter

log = logging.getLogger("amrst_gui.campaign")


class BatchEvents(QObject):
    """A batch's trees starting and ending, sent from the threads that learn of them
    (the job's, Dask's) to the dock on the GUI thread."""

    started = Signal(str)  # a Dask worker started the tree
    ended = Signal(str, str)  # tree id, its state or error ("": its worker ended)


class _BatchProgress:
    """The batch's ``BatchProgress`` for the dock: the share done to the job's
    reporter, each tree's result as :attr:`BatchEvents.ended`, Cancel heeded."""

    def __init__(self, reporter: Reporter, events: BatchEvents) -> None:
        self.reporter, self.events = reporter, events

    def update(
        self,
        done: int,
        errors: int,
        running: int,
        total: int,
        left_s: float | None,
        row: dict | None,
    ) -> None:
        self.reporter.progress((done + errors) / total if total else 1.0)
        if row is not None:
            what = row.get("status") or row.get("error", "")
            self.events.ended.emit(row["id"], str(what))
        self.reporter.check_cancelled()

    def check_cancelled(self) -> None:
        self.reporter.check_cancelled()


def run_batch_job(
    root: str, workers: int, events: BatchEvents, reporter: Reporter
) -> BatchSummary:
    """Run remaining (in a worker thread): the campaign's pending trees on Dask."""
    from amrst.campaign.batch import run_batch
    from amrst.campaign.manifest import load_campaign

    def on_worker_event(tree_id: str, event: str) -> None:
        if event == "started":
            events.started.emit(tree_id)
        else:
            events.ended.emit(tree_id, "")

    return run_batch(
        load_campaign(root),
        workers=workers,
        progress=_BatchProgress(reporter, events),
        on_worker_event=on_worker_event,
    )


class CampaignPanel(QWidget):
    """Lists a campaign's trees; runs, accepts and exports them."""

    tree_selected = Signal(str, list)
    link_chosen = Signal(str, str, object)
    rows_changed = Signal()

    def __init__(self, parent: QWidget | None = None, workers: int = 0) -> None:
        from amrst.campaign.batch import DEFAULT_WORKERS

        super().__init__(parent)
        self.setObjectName("campaign_panel")
        self.workers = workers or DEFAULT_WORKERS
        self.campaign: Campaign | None = None
        self.rows: list[dict] = []
        self.job: StageJob | None = None
        self.batch = BatchTracker()  # queued and running trees of the batch
        self.events = BatchEvents(self)
        self.events.started.connect(self._tree_started)
        self.events.ended.connect(self._tree_ended)
        self._share = 0.0  # of the batch's trees done
        self.stored: StoredTree | None = None  # of the selected tree
        self._shown = (0, 1)  # the link of the selected tree the views show
        self.tree_scans = TreeScansPanel()
        self.title = QLabel("No campaign open")
        self.filter_edit = QLineEdit()
        self.filter_edit.setPlaceholderText("Filter trees (id or state)")
        self.filter_edit.setObjectName("campaign_filter")
        self.needs_person = QCheckBox("Needs a person")
        self.table = QTableWidget(0, len(COLUMNS))
        self.table.setObjectName("campaign_table")
        self.table.setHorizontalHeaderLabels(list(COLUMNS))
        self.table.setSelectionBehavior(QAbstractItemView.SelectionBehavior.SelectRows)
        self.table.setSelectionMode(QAbstractItemView.SelectionMode.ExtendedSelection)
        self.table.setEditTriggers(QAbstractItemView.EditTrigger.NoEditTriggers)
        self.table.verticalHeader().setVisible(False)
        self.table.horizontalHeader().setSectionResizeMode(
            QHeaderView.ResizeMode.Interactive
        )
        self._fit_columns()
        self.open_button = QPushButton("Open campaign…")
        buttons = self._decision_buttons()
        self.status = QLabel("")
        # A long message (a path, several trees' errors) wraps; it never widens the
        # dock, and so the window, past the screen.
        self.status.setWordWrap(True)
        self.status.setSizePolicy(
            QSizePolicy.Policy.Ignored, QSizePolicy.Policy.Preferred
        )
        filters = QHBoxLayout()
        filters.addWidget(self.filter_edit)
        filters.addWidget(self.needs_person)
        layout = QVBoxLayout(self)
        top = QHBoxLayout()
        top.addWidget(self.title, 1)
        top.addWidget(self.open_button)
        layout.addLayout(top)
        layout.addLayout(filters)
        split = QSplitter(Qt.Orientation.Vertical)
        split.setObjectName("campaign_split")
        split.addWidget(self.table)
        split.addWidget(self.tree_scans)
        split.setStretchFactor(0, 3)  # the trees get the room; the scans a few rows
        split.setStretchFactor(1, 2)
        layout.addWidget(split, 1)
        layout.addLayout(buttons)
        layout.addWidget(self.status)
        self.filter_edit.textChanged.connect(self._apply_filter)
        self.needs_person.toggled.connect(self._apply_filter)
        self.table.itemSelectionChanged.connect(self._on_selection)
        self.open_button.clicked.connect(self._choose_folder)
        self.tree_scans.link_selected.connect(self.show_link)
        self._update_buttons()

    def _decision_buttons(self) -> QGridLayout:
        """Accept, Reject, Clear; Run and Export accepted under them, connected.

        Two rows keep the dock narrow enough for the Scans dock it shares the side
        with on a laptop screen.
        """
        self.run_button = QPushButton("Run remaining")
        self.accept_button = QPushButton("Accept")
        self.reject_button = QPushButton("Reject")
        self.clear_button = QPushButton("Clear")
        self.clear_button.setToolTip("Take the decision on the selected trees back")
        self.export_button = QPushButton("Export accepted")
        grid = QGridLayout()
        for col, b in enumerate(
            (self.accept_button, self.reject_button, self.clear_button)
        ):
            grid.addWidget(b, 0, 2 * col, 1, 2)
        grid.addWidget(self.run_button, 1, 0, 1, 3)
        grid.addWidget(self.export_button, 1, 3, 1, 3)
        self.run_button.clicked.connect(self._run_or_cancel)
        self.accept_button.clicked.connect(lambda: self.decide("accepted"))
        self.reject_button.clicked.connect(lambda: self.decide("rejected"))
        self.clear_button.clicked.connect(lambda: self.decide(CLEAR))
        self.export_button.clicked.connect(self.export_accepted)
        return grid

    # ------------------------------------------------------------- public
    def open_campaign(self, folder: str | Path) -> bool:
        """Read a campaign folder (manifest and results); False with a message if not."""
        from amrst.campaign.manifest import load_campaign

        if self.job is not None:
            self._say(
                f"{self.campaign.name if self.campaign else 'A campaign'} is running a "
                "batch or an export: open another when it ends."
            )
            return False
        try:
            self.campaign = load_campaign(folder)
        except AmrstError as exc:
            self._say(str(exc))
            return False
        self.title.setText(f"{self.campaign.name}: {len(self.campaign.trees)} trees")
        self.refresh()
        return True

    def refresh(self) -> None:
        """Re-read the manifest and every tree's state from the campaign folder, and
        redraw the table (a manifest edited by hand shows; a broken one is said, and
        the list stays as read last)."""
        from amrst.campaign.manifest import load_campaign
        from amrst.campaign.review import review_state
        from amrst.campaign.table import campaign_rows

        if self.campaign is None:
            return
        ids = self.selected_ids()
        shown = self.campaign.tree(ids[0]) if len(ids) == 1 else None
        try:
            self.campaign = load_campaign(self.campaign.root)
        except AmrstError as exc:
            self._say(f"{exc} The list shows the manifest as read before.")
        now = {t.id: t for t in self.campaign.trees}
        if shown is not None and now.get(shown.id) != shown:  # edited by hand
            if shown.id in now:  # listed and shown again from its new entry
                QTimer.singleShot(0, self, self._on_selection)
            else:
                self.stored = None
                self.tree_scans.show_tree(None, None, (0, 1))
        self.title.setText(f"{self.campaign.name}: {len(self.campaign.trees)} trees")
        self.rows = campaign_rows(self.campaign)
        for row in self.rows:
            row["read_state"] = review_state(
                self.campaign, row["tree_id"], row["status"]
            )
        self._restate()

    def _reread(self, tree_ids: list[str]) -> None:
        """Read the rows of ``tree_ids`` again (their new results), and redraw; the
        other trees' files have not changed."""
        from amrst.campaign.review import review_state
        from amrst.campaign.table import tree_row

        assert self.campaign is not None  # a batch runs on the campaign shown
        entries = {t.id: t for t in self.campaign.trees}
        for row in self.rows:
            entry = entries.get(row["tree_id"])
            if row["tree_id"] in tree_ids and entry is not None:
                row.update(tree_row(self.campaign, entry))
                row["read_state"] = review_state(self.campaign, entry.id, row["status"])
        self._restate()

    def _restate(self) -> None:
        """Redraw the table with the batch's queued and running trees over the states
        the folder gave last (no file is read: a tree that starts changes no file)."""
        from amrst.campaign.review import STATE_ORDER

        for row in self.rows:
            row["state"] = self.batch.state(row["read_state"], row["tree_id"])
        self.rows.sort(key=lambda r: (STATE_ORDER.index(r["state"]), r["tree_id"]))
        self._fill()
        self.rows_changed.emit()

    def state_of(self, tree_id: str) -> str:
        """Return the state shown for one tree."""
        return next(r["state"] for r in self.rows if r["tree_id"] == tree_id)

    def select_tree(self, tree_id: str) -> None:
        """Select one tree's row (as a click does)."""
        for i in range(self.table.rowCount()):
            if self._id_at(i) == tree_id:
                self.table.selectRow(i)
                index = self.table.model().index(i, 0)
                center = QAbstractItemView.ScrollHint.PositionAtCenter
                self.table.scrollTo(index, center)  # and again once laid out
                QTimer.singleShot(0, partial(self.table.scrollTo, index, center))
                return

    def selected_ids(self) -> list[str]:
        """Return the ids of the selected rows."""
        rows = sorted({i.row() for i in self.table.selectedIndexes()})
        return [self._id_at(r) for r in rows]

    def _id_at(self, row: int) -> str:
        item = self.table.item(row, 0)
        return "" if item is None else item.text()

    def decide(self, decision: str) -> None:
        """Accept, reject or clear the selected trees; written to the folder now.

        Accepting a tree the batch did not register asks first (:meth:`confirm`,
        with ``amrst.campaign.review.acceptance_warning``'s words).
        """
        from amrst.campaign.review import ACCEPTED, acceptance_warning, decide

        if self.campaign is None:
            return
        for tree_id in self.selected_ids():
            warning = ""
            if decision == ACCEPTED:
                warning = acceptance_warning(self.campaign, tree_id)
                if warning and not self.confirm(f"{warning} Accept it anyway?"):
                    continue
            try:
                decide(
                    self.campaign,
                    [tree_id],
                    decision,
                    confirm_unregistered=bool(warning),
                )
            except AmrstError as exc:
                self._say(str(exc))
        self.refresh()

    def confirm(self, question: str) -> bool:
        """Ask a yes/no question; True for yes."""
        answer = QMessageBox.question(self, "AMRST Studio", question)
        return answer == QMessageBox.StandardButton.Yes

    def export_accepted(self) -> None:
        """Write the merged cloud of every accepted tree, in the engine process (the
        scans are read again), and say where it went."""
        from amrst.campaign.review import export_accepted
        from amrst_gui import engine_process

        if self.campaign is None or self.job is not None:
            return
        self._say("Exporting the accepted trees…")
        self.job = run_stage(
            engine_process.in_engine(export_accepted, what="the campaign export"),
            self.campaign,
            "ply",
            name="campaign export",
            on_progress=lambda f, m: self._say(f"{f:.0%}: {m}"),
            on_result=self._on_exported,
            on_error=lambda exc: self._say(f"Export stopped: {exc}"),
        )
        self.job.ended.connect(self._on_finished)
        self.refresh()

    def _on_exported(self, result: tuple[list[Path], dict[str, str]]) -> None:
        written, errors = result
        where = sorted({str(p.parent.parent) for p in written})
        text = f"Exported {len(written)} accepted tree(s)" + (
            f" to {', '.join(where)} (merged.ply in each tree's folder)."
            if written
            else "."
        )
        text += "".join(f" {tree}: {why}" for tree, why in errors.items())
        self._say(text)

    def run_remaining(self) -> None:
        """Register every tree not done yet, in the background (Dask)."""
        if self.campaign is None or self.job is not None:
            return
        self.refresh()  # the trees as campaign.toml lists them now, as the batch will
        # Queued until a worker starts them (its event marks them running).
        self.batch.submit(
            {
                r["tree_id"]
                for r in self.rows
                if r["state"] in ("not run", "failed", OUT_OF_DATE)
            }
        )
        self.refresh()
        self._share = 0.0
        self.job = run_stage(
            run_batch_job,
            str(self.campaign.root),
            self.workers,
            self.events,
            name="campaign batch",
            on_progress=self._on_progress,
            on_result=self._on_done,
            on_error=self._on_error,
        )
        self.job.ended.connect(self._on_finished)
        self._update_buttons()

    def cancel(self) -> None:
        """Stop the batch or the export; the trees in flight are lost, as with a
        kill (the batch closes its cluster)."""
        if self.job is not None:
            self.job.cancel()

    def _run_or_cancel(self) -> None:
        """The Run button is Cancel while the dock's batch or export runs."""
        if self.job is not None:
            self.cancel()
        else:
            self.run_remaining()

    # ----------------------------------------------------------- plumbing
    def _fill(self) -> None:
        self.table.blockSignals(True)
        selected = set(self.selected_ids())
        self.table.setRowCount(len(self.rows))
        keep = QItemSelection()  # the same trees, wherever their rows moved
        last = len(COLUMNS) - 1
        for i, row in enumerate(self.rows):
            for j, text in enumerate(row_cells(row)):
                item = QTableWidgetItem(text)
                if j == 1 and row["error"]:
                    item.setToolTip(row["error"])
                self.table.setItem(i, j, item)
            if row["tree_id"] in selected:
                model = self.table.model()
                keep.select(model.index(i, 0), model.index(i, last))
        # Not selectRow: it reads the keyboard's modifiers and may add to, or replace,
        # the selection.
        self.table.selectionModel().select(
            keep, QItemSelectionModel.SelectionFlag.ClearAndSelect
        )
        self.table.blockSignals(False)
        self._fit_columns()
        self._apply_filter()
        self._update_buttons()

    def _fit_columns(self) -> None:
        """Size each column to its contents, never narrower than its whole title."""
        self.table.resizeColumnsToContents()
        header = self.table.horizontalHeader()
        metrics = header.fontMetrics()
        for j, title in enumerate(COLUMNS):
            need = metrics.horizontalAdvance(title) + 20  # the header's margins
            if header.sectionSize(j) < need:
                header.resizeSection(j, need)

    def _apply_filter(self) -> None:
        text, only = self.filter_edit.text(), self.needs_person.isChecked()
        for i, row in enumerate(self.rows):
            self.table.setRowHidden(i, row_hidden(row, text, only))

    def show_link(self, target: int, source: int) -> None:
        """Show one link of the selected tree: emits ``link_chosen`` with its stored
        result (None when the tree has none or a scan was not reached)."""
        ids = self.selected_ids()
        if len(ids) != 1 or self.campaign is None:
            return
        entry = self.campaign.tree(ids[0])
        if max(target, source) >= len(entry.scans):  # a listing of an older manifest
            return
        stored = self.stored
        result = None if stored is None else stored.link_result(target, source)
        self._shown = (target, source)
        self.tree_scans.mark_shown((target, source))
        self.link_chosen.emit(
            str(self.campaign.root / entry.scans[target]),
            str(self.campaign.root / entry.scans[source]),
            result,
        )

    def keep_shown(self, target: Path | None, source: Path | None) -> None:
        """A chosen link was not opened (the switch declined, or a step runs): select
        and list again the tree whose scans the views show (``target``, ``source``),
        or none, so that the selection, which Accept and Reject act on, is never a
        tree the views do not show."""
        found = self._tree_of(target, source)
        tree_id, link = found if found is not None else ("", (0, 1))
        model, last = self.table.model(), len(COLUMNS) - 1
        keep = QItemSelection()
        for i in range(self.table.rowCount()):
            if tree_id and self._id_at(i) == tree_id:
                keep.select(model.index(i, 0), model.index(i, last))
        self.table.blockSignals(True)
        self.table.selectionModel().select(
            keep, QItemSelectionModel.SelectionFlag.ClearAndSelect
        )
        self.table.blockSignals(False)
        if found is None:
            self.stored = None
            self.tree_scans.show_tree(None, None, (0, 1))
        else:
            self._list_tree(tree_id)
            self._shown = link
            self.tree_scans.mark_shown(link)
        self._update_buttons()

    def _tree_of(
        self, target: Path | None, source: Path | None
    ) -> tuple[str, tuple[int, int]] | None:
        """The tree and link whose scans are ``target`` and ``source``, or None."""
        if self.campaign is None or target is None or source is None:
            return None
        for entry in self.campaign.trees:
            scans = [self.campaign.root / scan for scan in entry.scans]
            if target in scans and source in scans:
                return entry.id, (scans.index(target), scans.index(source))
        return None

    def _on_selection(self) -> None:
        self._update_buttons()
        ids = self.selected_ids()
        if len(ids) != 1 or self.campaign is None:
            return
        entry = self.campaign.tree(ids[0])
        order = [entry.reference] + [
            k for k in range(len(entry.scans)) if k != entry.reference
        ]
        shown = self._list_tree(ids[0])
        self.tree_selected.emit(
            ids[0], [str(self.campaign.root / entry.scans[k]) for k in order]
        )
        self.show_link(*shown)

    def _list_tree(self, tree_id: str) -> tuple[int, int]:
        """Read a tree's stored result (no registration) and list its scans and
        links; return the link to show first."""
        from amrst.campaign.stored import read_stored_tree

        assert self.campaign is not None  # only with a tree selected
        entry = self.campaign.tree(tree_id)
        self.stored = read_stored_tree(self.campaign, tree_id)
        others = [k for k in range(len(entry.scans)) if k != entry.reference]
        shown = (entry.reference, others[0])
        if self.stored is not None:
            shown = self.stored.default_link()
        self.tree_scans.show_tree(entry, self.stored, shown)
        return shown

    def _on_progress(self, fraction: float, message: str) -> None:
        self._share = fraction

    def _tree_started(self, tree_id: str) -> None:
        self.batch.start(tree_id)
        self._restate()  # its files are as they were

    def _tree_ended(self, tree_id: str, what: str) -> None:
        if what:  # the batch has its result
            self._say(f"{self._share:.0%} of the trees done; last: {tree_id}: {what}")
        if not self.batch.end(tree_id):
            return
        self._reread([tree_id])  # a tree's new result: its row read again
        if self.selected_ids() == [tree_id]:  # its links are new: list them
            self._list_tree(tree_id)
            self.tree_scans.mark_shown(self._shown)  # the views keep theirs

    def _on_done(self, summary) -> None:
        self._say(f"Batch done: {summary.counts()}.")

    def _on_error(self, exc: BaseException) -> None:
        self._say(f"Batch stopped: {exc}")

    def _on_finished(self) -> None:
        # On the worker thread's end, not the job's: a cancelled batch is reported at
        # once while its thread still closes the cluster (seconds), and another run
        # must not start before.
        self.job = None
        self.batch.clear()
        self.refresh()

    def _choose_folder(self) -> None:
        from PySide6.QtWidgets import QFileDialog

        folder = QFileDialog.getExistingDirectory(self, "Open a campaign folder")
        if folder:
            self.open_campaign(folder)

    def _update_buttons(self) -> None:
        has = self.campaign is not None
        stopping = self.job is not None and self.job.reporter.cancelled
        self.run_button.setEnabled(has and not stopping)
        self.run_button.setText(
            "Stopping…"
            if stopping
            else "Cancel"
            if self.job is not None
            else "Run remaining"
        )
        picked = bool(self.selected_ids())
        self.accept_button.setEnabled(has and picked)
        self.reject_button.setEnabled(has and picked)
        self.clear_button.setEnabled(has and picked)
        self.export_button.setEnabled(
            has
            and self.job is None
            and any(r["state"] == "accepted" for r in self.rows)
        )

    def _say(self, text: str) -> None:
        self.status.setText(text)
        self.status.setToolTip(text)
        log.info("%s", text)

    def shutdown(self) -> None:
        """Cancel a running batch (the window is closing)."""
        if self.job is not None:
            self.job.discard()
