"""The Plot window: a plot's scans, registered and inventoried, and its stem map.

``open_scans(paths)`` takes the plot's scans (the first is the reference); Run asks
for the results folder if none is set, asks before replacing a plot already there,
and runs ``jobs.run_plot`` (``amrst plot SCANS --out DIR``) in the engine
process through ``workers.run_stage``: progress below the buttons, Cancel stops it
at once, a failure is one line. The result shows as the stem map (centre), the
links and trees (left) and the selected tree (right). A mark (ok / check) and an
accepted link are written to ``review.json`` in the results folder the moment they are
made (``amrst.plot.review``); the window shows the run as that review leaves it
(``jobs.reviewed``). ``open_results(folder)`` shows a plot written before (by
the app or ``amrst plot``) the same way, without running it.

A link is checked and placed by hand: **Open pair** calls ``open_pair_in(scan i, scan
j, its pose as a stored result or None)`` (the main window sets it; it returns "" or
why the scans were not opened), so the main window shows the two scans at the link's
pose (overlay, verdict), where the Manual pose dock picks point pairs and
saves them as a CSV; **Use pairs…** takes that file for the selected link, and the
next run places the link from it (``amrst plot --pairs``). A link that needs review
and looks right is accepted at its pose (**Accept**, asked first); the scans it places
then read *accepted*.
"""

from __future__ import annotations

import logging
import math
import re
from dataclasses import replace
from pathlib import Path
from typing import TYPE_CHECKING

from PySide6.QtCore import Qt, Signal
from PySide6.QtGui import QKeySequence, QShortcut
from PySide6.QtWidgets import (
    QCheckBox,
    QFileDialog,
    QHBoxLayout,
    QLabel,
    QLineEdit,
    QMainWindow,
    QMessageBox,
    QProgressBar,
    QPushButton,
    QSplitter,
    QVBoxLayout,
    QWidget,
)

from amrst.errors import AmrstError, Cancelled, InvalidInput
from amrst.files.folderlock import FolderBusy
from amrst.plot.export import inventory_rows
from amrst.plot.inventory import seen_from_any
from amrst.plot.review import (
    ACCEPTED,
    FOLLOW_M,
    REVIEW_JSON,
    PlotReview,
    read_review,
    write_review,
)
from amrst.plot.stand import PlotArea, counted, stand, stand_line
from amrst.review.verdict import NEEDS_REVIEW, REGISTERED
from amrst_gui.app import fit_screen
from amrst_gui.panels.verdict_style import ERROR_STYLE
from amrst_gui.plot import jobs, menus
from amrst_gui.plot.area import AreaRow
from amrst_gui.plot.links import LinksPanel
from amrst_gui.plot.scans import ScansPanel
from amrst_gui.plot.stem_map import NO_PLOT, StemMapView
from amrst_gui.plot.tables import (
    NBSP,
    scan_file_exists,
)
from amrst_gui.plot.tree import TreePanel
from amrst_gui.plot.tree_list import TreeList

if TYPE_CHECKING:
    from collections.abc import Callable

    from amrst.campaign.stored import StoredLinkResult
    from amrst.plot.review import HandCircle
    from amrst_gui.plot.jobs import PlotOutcome
    from amrst_gui.workers import StageJob

log = logging.getLogger("amrst_gui.plot")

RESULT_FILES = f"trees.csv, plot.json, {REVIEW_JSON}"


def ask_scans(parent: QWidget, settings) -> list[str]:
    """Ask for a plot's scans; sorted by name, numbers by value (scan_2 before
    scan_10), so scan_1 is the reference (the window's Make reference picks another)."""
    from amrst import io

    patterns = " ".join(f"*{ext}" for ext in io.supported_extensions())
    start = str(settings.value("dirs/open", "", type=str) or Path.home())
    paths, _ = QFileDialog.getOpenFileNames(
        parent,
        "Open a plot: its scans (the first by name is the reference)",
        start,
        f"Point clouds ({patterns});;All files (*)",
    )
    if paths:
        settings.setValue("dirs/open", str(Path(paths[0]).parent))
    return sorted(paths, key=by_name)


def by_name(path: str) -> list[tuple[int, int | str]]:
    """Sort key of a file path: its text, with each run of digits taken as a number."""
    return [
        (0, int(part)) if part.isdigit() else (1, part.casefold())
        for part in re.split(r"(\d+)", path)
        if part
    ]


def _scanner_centre(o: PlotOutcome) -> tuple[float, float]:
    """Where the reference's scanner stood (file coordinates), else the origin: the
    plot centre ``amrst plot`` takes without ``--plot-centre``."""
    xy = o.scans[0].xy if o.scans else None
    if xy is None:
        return (0.0, 0.0)
    return (float(xy[0] + o.reference_at[0]), float(xy[1] + o.reference_at[1]))


def _stamp(out: Path) -> tuple[int, int] | None:
    """When plot.json in ``out`` was written, and its size (None: there is none)."""
    from amrst.plot.export import PLOT_JSON

    try:
        st = (out / PLOT_JSON).stat()
    except OSError:
        return None
    return st.st_mtime_ns, st.st_size


def _run_choices(
    o: PlotOutcome,
) -> tuple[
    set[tuple[int, int]],
    dict[tuple[int, int], str],
    dict[int, tuple[float, float, float]],
]:
    """The links a run left out, placed from point pairs, and the scanners given."""
    from amrst.plot.register import LEFT_OUT_ORIGIN

    return (
        {ln.key for ln in o.links if ln.origin == LEFT_OUT_ORIGIN},
        {ln.pairs[0]: ln.pairs[1] for ln in o.links if ln.pairs},
        {k: s.given for k, s in enumerate(o.scans) if s.given is not None},
    )


def _same_tree(before: PlotOutcome, k: int, now: PlotOutcome) -> int | None:
    """The tree of ``now`` that stands where tree ``k`` of ``before`` stood, as a
    mark given to it follows it (``FOLLOW_M`` of its breast-height centre; None:
    none there, or the plot has another reference)."""
    if now.labels[:1] != before.labels[:1] or not now.trees:
        return None
    was = before.tree_xy[k]
    d = [math.dist(xy, was) for xy in now.tree_xy]
    nearest = min(range(len(d)), key=d.__getitem__)
    return nearest if d[nearest] <= FOLLOW_M else None


def _numbered(o: PlotOutcome, labels: list[str]) -> str:
    """Scans by number and file, "S3 (source.ply)": two scans may share a name."""
    return ", ".join(f"S{o.labels.index(s) + 1} ({Path(s).name})" for s in labels)


def ask_close(parent: QWidget, text: str) -> bool:
    """Ask whether the Plot window may close although ``text`` says what it drops."""
    return confirm(parent, "Close the plot window?", text)


def confirm(parent: QWidget, title: str, text: str) -> bool:
    """Ask Yes / Cancel (Cancel the default); tests answer it themselves."""
    answer = QMessageBox.question(
        parent,
        title,
        text,
        QMessageBox.StandardButton.Yes | QMessageBox.StandardButton.Cancel,
        QMessageBox.StandardButton.Cancel,
    )
    return answer == QMessageBox.StandardButton.Yes


class PlotWindow(QMainWindow):
    """Open, run and review one plot. Emits ``plot_done(outcome)`` when a run's or
    a results folder's plot shows."""

    plot_done = Signal(object)

    def __init__(self, parent: QWidget | None = None) -> None:
        super().__init__(parent)
        self.setObjectName("plot_window")
        self.setWindowTitle("AMRST Studio: plot")
        self.found: PlotOutcome | None = None  # the run's outcome
        self.outcome: PlotOutcome | None = None  # as the review leaves it
        self.review = PlotReview()  # marks, DBHs by hand, links accepted
        # Why the folder's review.json could not be read: no review is written over it.
        self.review_error: str | None = None
        self._close_agreed = False  # the user let the window close with choices unrun
        self._shown_specs: list[str] = []  # the scans of the plot shown, as listed
        # plot.json as the plot shown was read: a run from elsewhere into the same
        # folder changes it, and the window then writes nothing over that run.
        self.shown_stamp: tuple[int, int] | None = None
        # Opens a link's two scans in the main window; returns "" or why not.
        self.open_pair_in: Callable[[str, str, StoredLinkResult | None], str] | None = (
            None
        )
        self.job: StageJob | None = None
        self.report_job: StageJob | None = None
        self.listing = False  # the job lists the scans of a file of several
        self.opening = False  # the job reads a results folder
        self.run_queued = False  # Run was asked for while listing or opening
        # The side column's parts, top to bottom; the map; the selected tree.
        self.scans = ScansPanel()
        self.scans.said.connect(self._say)
        self.scans.reordered.connect(self._on_reordered)
        self.area_row = AreaRow()
        self.area_row.edited.connect(self.apply_area)
        self.area_row.picking.connect(self._picking_centre)
        self.links = LinksPanel()
        self.links.said.connect(self._say)
        self.links.open_asked.connect(self.open_pair)
        self.links.accept_asked.connect(self.toggle_accept)
        self.trees = TreeList()
        self.trees.chosen.connect(self.select_tree)
        self.trees.adding.connect(self._adding_tree)
        self.trees.report_asked.connect(self.write_report)
        self.trees.export_asked.connect(lambda: self.export_inventory())
        self.stem_map = StemMapView()
        self.tree_panel = TreePanel()
        split = QSplitter(Qt.Orientation.Horizontal)
        split.addWidget(self._build_side())
        split.addWidget(self.stem_map)
        split.addWidget(self.tree_panel)
        # A wider window widens the map and, by half as much, the tree's slice (where
        # a DBH is measured by hand); the lists keep their width.
        split.setStretchFactor(0, 0)
        split.setStretchFactor(1, 2)
        split.setStretchFactor(2, 1)
        split.setSizes([480, 530, 330])  # the lists: every tree column at 1366 px
        self.setCentralWidget(split)
        self.stem_map.tree_clicked.connect(self.select_tree)
        self.stem_map.point_clicked.connect(self._on_map_point)
        self.tree_panel.mark_chosen.connect(self.set_mark)
        self.tree_panel.dbh_chosen.connect(self.set_hand_dbh)
        for key, step in (("N", 1), ("P", -1)):  # the next / previous tree
            QShortcut(QKeySequence(key), self, lambda step=step: self.step_tree(step))
        self.plot_menu = menus.build(self)
        fit_screen(self, 1500, 950)

    def _build_side(self) -> QWidget:
        side = QWidget()
        self.out_edit = QLineEdit()
        self.out_edit.setPlaceholderText("results folder (asked at Run)")
        self.choose_button = QPushButton("Choose…")
        self.choose_button.clicked.connect(self.choose_out)
        self.run_button = QPushButton("Run plot")
        self.run_button.setToolTip(
            "Register the scans by their stems and list every tree (amrst plot); "
            "the results are written into the results folder"
        )
        self.run_button.clicked.connect(self.run)
        self.cancel_button = QPushButton("Cancel")
        self.cancel_button.setToolTip("Stop the running plot; nothing is written (Esc)")
        self.cancel_button.setEnabled(False)
        self.cancel_button.clicked.connect(self.cancel)
        self.cloud_check = QCheckBox("plot.laz")
        self.cloud_check.setToolTip(
            "Also write the registered plot, plot.laz: every placed scan in the "
            "reference's frame, scan_id its number, tree its row in trees.csv "
            "(amrst plot --write-cloud)"
        )
        self.progress = QProgressBar()
        self.progress.setRange(0, 1000)
        self.progress.setTextVisible(False)
        self.progress.setMaximumHeight(10)
        self.status = QLabel(
            "Open a plot's scans (Plot ▸ Open plot…), or the results of one run "
            "before (Plot ▸ Open plot results…)."
        )
        self.status.setObjectName("plot_status")
        self.status.setWordWrap(True)
        # Room for three lines from the start: the tables below stay put as the
        # messages come and go.
        self.status.setAlignment(Qt.AlignmentFlag.AlignTop | Qt.AlignmentFlag.AlignLeft)
        self.status.setMinimumHeight(3 * self.status.fontMetrics().lineSpacing())
        folder = QHBoxLayout()
        folder.addWidget(self.out_edit, 1)
        folder.addWidget(self.choose_button)
        buttons = QHBoxLayout()
        buttons.addWidget(self.run_button)
        buttons.addWidget(self.cancel_button)
        buttons.addWidget(self.cloud_check)
        buttons.addStretch(1)
        layout = QVBoxLayout(side)
        layout.setContentsMargins(6, 4, 6, 4)
        layout.addWidget(self.scans)
        layout.addWidget(QLabel(f"<b>Results folder</b>: {RESULT_FILES}"))
        layout.addLayout(folder)
        layout.addLayout(buttons)
        layout.addWidget(self.area_row)
        layout.addWidget(self.progress)
        layout.addWidget(self.status)
        layout.addWidget(self.links)
        layout.addWidget(self.trees, 1)
        self._update_tree_buttons()
        return side

    # ------------------------------------------------------------- public
    @property
    def busy(self) -> bool:
        return self.job is not None

    @property
    def running(self) -> bool:
        """Whether the job is a plot run (not a listing of scans, nor an opening)."""
        return self.busy and not (self.listing or self.opening)

    def open_scans(self, paths: list, out: Path | None = None) -> bool:
        """Take the plot's scans and results folder (None: Run asks for one; a
        relative one is the working directory's, as on the command line); False
        while a run goes on.

        A file of several scans (E57, PTX) is listed as its scans, one a line, as a
        run numbers them: the engine process reads its headers first. A folder that
        holds a run of these scans shows it (:meth:`_scans_taken`).
        """
        from amrst.io.scans import names_several
        from amrst_gui import engine_process, workers

        if self.busy:
            self._say_busy()
            return False
        self._clear_plot()
        # Another plot's folder would take this one's results over its own, and
        # its area would be written into this one's: without a folder given, Run
        # asks for one.
        self._set_out("" if out is None else str(Path(out).expanduser().absolute()))
        self.area_row.show_area(None)
        if any(names_several(p) for p in paths):
            self._take_scans([])
            self._say("Listing the scans of the files…")
            self.listing = True
            self.job = workers.run_stage(
                engine_process.in_engine(
                    jobs.scan_specs, what="the Plot window's listing of scans"
                ),
                [str(p) for p in paths],
                name="list scans",
                on_result=self._scans_listed,
                on_error=self._on_error,
            )
            self._show_busy()
            return True
        self._take_scans(paths)
        if paths:
            self._scans_taken()
        return True

    def _clear_plot(self) -> None:
        """Show no plot, and drop what the next run took from the one shown: its
        review, and the links placed from point pairs or left out (they name scans
        by their numbers)."""
        self.found = self.outcome = None
        self.review, self.review_error = PlotReview(), None
        self.links.set_choices(set(), {})
        self.stem_map.set_plot(None)
        self.tree_panel.show_tree(None, None, None)
        self.links.show_links(None)
        self.trees.show_trees(None, self.review, None)

    def _scans_listed(self, listed: list[tuple[str, str]]) -> None:
        self.job, self.listing = None, False
        self.scans.name(listed)
        self._take_scans([spec for spec, _name in listed])
        self._scans_taken()

    def _scans_taken(self) -> None:
        """Show the plot of these scans the results folder holds, if it does (as
        Open plot results… would); else say what Run does, and run if asked to
        meanwhile."""
        text = self.out_edit.text().strip()
        if text and jobs.run_of(Path(text).expanduser(), self.scans.specs):
            self._open(Path(text).expanduser())
            return
        self._say_scans()
        if self.run_queued:
            self.run_queued = False
            self.run()

    def _say_busy(self) -> None:
        if self.listing:
            self._say("The scans are being listed: wait, or cancel it.", error=True)
        elif self.opening:
            self._say("A plot is being opened: wait, or cancel it.", error=True)
        else:
            self._say("A plot is running: cancel it first.", error=True)

    def _say_scans(self) -> None:
        gone = [
            k + 1 for k, s in enumerate(self.scans.specs) if not scan_file_exists(s)
        ]
        if len(self.scans.specs) < 2:
            self._say("A plot needs two or more scans: open them together.", error=True)
        elif gone:
            self._say(
                f"Not found: {', '.join(f'S{k}' for k in gone)}. Open the plot's "
                "scans where they are now (File ▸ Open plot…).",
                error=True,
            )
        else:
            self._say(
                f"{len(self.scans.specs)} scans. Run plot registers and inventories them."
            )

    def open_results(self, out: Path) -> bool:
        """Show the plot a results folder holds, without running it; False while a
        run goes on.

        Its scans become the window's (Run plot runs them again into that folder), and
        so do the links it placed from point pairs or left out.
        """
        if self.busy:
            self._say_busy()
            return False
        out = Path(out).expanduser().absolute()  # said as it is, wherever the app runs
        self.open_scans([], out)
        self._open(out)
        return True

    def _open(self, out: Path) -> None:
        """Read the plot ``out`` holds in a worker, then show it (``_on_result``)."""
        from amrst_gui import workers

        self.setWindowTitle(f"AMRST Studio: plot in {out}")
        self._say(f"Opening the plot in {out}…")
        self.opening = True
        self.job = workers.run_stage(
            jobs.open_results,
            Path(out),
            name="open plot",
            on_result=lambda o: self._on_result(o, opened=True),
            on_error=self._on_error,
        )
        self._show_busy()

    def _take_scans(self, paths: list) -> None:
        """The scans the next run reads, listed (the first is the reference)."""
        self.scans.take(paths)
        self._scans_changed()

    def _on_reordered(self) -> None:
        """The scans listed changed (Make reference, Remove): the plot shown is not
        of them; the results folder and the plot area stay."""
        self._clear_plot()
        self._scans_changed()

    def _scans_changed(self) -> None:
        """Show what the scans listed now allow: the map's hint, the title, Run."""
        self.stem_map.empty_text = (
            "Run plot registers the scans listed and draws the plot here."
            if self.scans.specs
            else NO_PLOT
        )
        self.stem_map.update()
        self._show_title()
        self._show_busy()

    def _show_title(self) -> None:
        """Name the scans in the window's title (none: the plain title)."""
        names = ", ".join(Path(s).name for s in self.scans.specs)
        self.setWindowTitle(
            f"AMRST Studio: plot of {names}" if names else "AMRST Studio: plot"
        )

    def choose_out(self) -> None:
        """Ask for the results folder."""
        start = self.out_edit.text() or (
            str(Path(self.scans.specs[0]).parent)
            if self.scans.specs
            else str(Path.home())
        )
        folder = QFileDialog.getExistingDirectory(
            self, "Results folder of the plot", start
        )
        if folder:
            self._set_out(folder)

    def _set_out(self, folder: str) -> None:
        """Take the results folder ("": none); tick plot.laz when it already holds one
        (a run again then writes it anew rather than removing it)."""
        from amrst.plot.export import PLOT_CLOUD

        self.out_edit.setText(folder)
        self.cloud_check.setChecked(
            bool(folder) and (Path(folder).expanduser() / PLOT_CLOUD).is_file()
        )

    def run(self) -> None:
        """Register and inventory the plot in the engine process.

        Asked for while the scans of a file are listed, or the results folder's plot
        of them opened, it runs once that is done.
        """
        from amrst_gui import dialogs, engine_process, workers

        if self.listing or self.opening:
            self.run_queued = True
            return
        if self.busy or len(self.scans.specs) < 2:
            return
        try:
            area = self.area_row.area()
        except InvalidInput as exc:
            self._say(f"Not run: {exc}", error=True)
            return
        if not self.out_edit.text().strip():
            self.choose_out()
        text = self.out_edit.text().strip()
        if not text:
            self._say("Choose a results folder to run the plot.", error=True)
            return
        out = Path(text).expanduser()
        if not out.is_absolute():  # a name typed: beside the scans, as Choose… starts
            out = Path(self.scans.specs[0]).parent / out
            self.out_edit.setText(str(out))
        overwrite = self._may_replace(out)
        if overwrite is None:
            self._say(f"Not run: {out} is kept as it is.", error=True)
            return
        if (lost := self.tree_panel.unkept()) and not dialogs.confirm_discard(
            self, "Running the plot", lost
        ):
            self._say("Not run: your DBH being measured is kept.", error=True)
            return
        self.progress.setValue(0)
        self._say("Running the plot…")
        self.job = workers.run_stage(
            engine_process.in_engine(
                jobs.run_plot, what="the plot run in the Plot window"
            ),
            list(self.scans.specs),
            out,
            overwrite,
            name="plot",
            pairs=dict(self.links.hand_pairs),
            left_out=set(self.links.left_out),
            scanners=dict(self.scans.given_scanners),
            write_cloud=self.cloud_check.isChecked(),
            area=area,
            on_result=self._on_result,
            on_error=self._on_error,
            on_progress=self._on_progress,
        )
        self._show_busy()

    def cancel(self) -> None:
        if self.job is not None:
            self.job.cancel()

    def open_pair(self) -> None:
        """Show the selected link's scans at its pose in the main window."""
        line = self.links.selected()
        if line is None:
            return
        i, j = line.target, line.source
        if self.open_pair_in is None:
            return
        why = self.open_pair_in(
            self.scans.specs[i], self.scans.specs[j], jobs.stored_link(line)
        )
        if why:
            self._say(f"S{i + 1} and S{j + 1} are not open: {why}", error=True)
            return
        at = "at the link's pose" if line.T_world is not None else "(no pose)"
        self._say(
            f"S{i + 1} (target) and S{j + 1} (source) are open in the main window "
            f"{at}: check them there; to place the link by hand, pick three or more "
            "points in both in the Manual pose dock, Save them, then Use pairs… here "
            "and Run plot."
        )

    def export_inventory(self, path: str | None = None) -> None:
        """Save the inventory with the marks as CSV or XLSX (asked when not given)."""
        from amrst.plot.export import export_inventory

        o = self.outcome
        if o is None:
            return
        if path is None:
            path, _ = QFileDialog.getSaveFileName(
                self,
                "Export the inventory",
                str(o.out / "inventory.csv"),
                "CSV (*.csv);;Excel (*.xlsx)",
            )
        if not path:
            return
        try:
            export_inventory(Path(path), o.trees, self.review, o.area, unsure=o.unsure)
        except (AmrstError, OSError) as exc:
            self._say(f"Not exported: {exc}", error=True)
            return
        self._say(
            f"{counted(len(o.trees), 'tree')}, with your marks and DBHs, exported to "
            f"{path}"
        )

    def write_report(self) -> None:
        """Write report.html from the results folder's files in the engine process,
        then open it (matplotlib draws the stem map: not in the app)."""
        from amrst_gui import engine_process, workers

        if self.outcome is None or self.report_job is not None:
            return
        self._say("Writing the report…")
        self.report_job = workers.run_stage(
            engine_process.in_engine(jobs.report_job, what="the plot report"),
            self.outcome.out,
            name="report",
            on_progress=lambda _f, message: self._say(message),
            on_result=self._on_report,
            on_error=self._on_report_error,
        )
        self._update_tree_buttons()

    def select_tree(self, k: int | None) -> None:
        """Show tree ``k`` (index into the outcome's trees) everywhere; a DBH being
        measured on another is asked about first."""
        from amrst_gui import dialogs

        o = self.outcome
        if o is None or k is None or not 0 <= k < len(o.trees):
            return
        shown, lost = self.stem_map.selected, self.tree_panel.unkept()
        if (
            lost
            and shown is not None
            and k != shown
            and not dialogs.confirm_discard(self, "Choosing another tree", lost)
        ):
            self.trees.select(shown, quiet=True)  # its row again, and nothing else
            return
        self.stem_map.select(k)
        self.tree_panel.show_tree(o, k, self.review)
        self.trees.select(k)

    def step_tree(self, step: int) -> None:
        """Select the tree ``step`` rows below the selected one in the list."""
        self.select_tree(self.trees.stepped(step))

    def keyPressEvent(self, event) -> None:
        """Esc cancels a running plot, else ends a click on the map awaited (what no
        child took)."""
        picking = self.trees.adding_tree or self.area_row.picking_centre
        if event.key() == Qt.Key.Key_Escape and self.job is not None:
            self.cancel()
        elif event.key() == Qt.Key.Key_Escape and picking:
            self.trees.stop_adding()
            self.area_row.stop_picking()
        else:
            super().keyPressEvent(event)

    def set_mark(self, tree_id: str, mark: str) -> None:
        """Mark a tree (``amrst.plot.review.MARKS``; "" clears); write the review and
        trees.csv."""
        marks, at = dict(self.review.marks), dict(self.review.at)
        trees = {t.tree_id: t for t in self.outcome.trees} if self.outcome else {}
        if mark and tree_id in trees:
            x, y = trees[tree_id].stem.dbh_xy[:2]
            marks[tree_id], at[tree_id] = mark, (float(x), float(y))  # follows it
        else:
            marks.pop(tree_id, None)
            at.pop(tree_id, None)
        done = f"{tree_id}: {mark or 'mark cleared'}"
        self._review_trees(replace(self.review, marks=marks, at=at), done, "The mark")

    def set_hand_dbh(self, tree_id: str, circle: HandCircle | None) -> None:
        """Keep the technician's DBH of a tree (None forgets it); write the review
        and trees.csv."""
        dbh = dict(self.review.dbh)
        if circle is not None:
            dbh[tree_id] = circle
            done = f"{tree_id}: your DBH {100 * circle.dbh_m:.1f} cm"
        else:
            dbh.pop(tree_id, None)
            done = f"{tree_id}: your DBH forgotten"
        self._review_trees(replace(self.review, dbh=dbh), done, "Your DBH")

    def _adding_tree(self, on: bool) -> None:
        if on:
            self.area_row.stop_picking()
        self.stem_map.set_adding(on or self.area_row.picking_centre)

    def _picking_centre(self, on: bool) -> None:
        if on:
            self.trees.stop_adding()
        self.stem_map.set_adding(on or self.trees.adding_tree)

    def _on_map_point(self, x: float, y: float) -> None:
        """A click on the map: the plot centre while picking it, else a tree added."""
        if not self.area_row.picking_centre:
            self.add_tree(x, y)
            return
        o = self.outcome
        if o is None:
            self.area_row.stop_picking()
            return
        # The centre is typed in the file's coordinates.
        self.area_row.set_centre((x + o.reference_at[0], y + o.reference_at[1]))

    def apply_area(self) -> None:
        """Give the plot shown the radius and centre of the fields, saved at once.

        Only the stand figures and trees.csv's ``in_plot`` change: no run is needed.
        """
        from amrst.plot.export import PLOT_JSON, TREES_CSV, write_area

        o = self.found
        if o is None or self.busy:
            return  # the next run takes the fields
        try:
            asked = self.area_row.area()
            area = (
                None
                if asked is None
                else PlotArea(asked[1] or _scanner_centre(o), asked[0])
            )
        except InvalidInput as exc:
            self._say(f"Plot area not changed: {exc}", error=True)
            return
        if area == o.area:
            if self.status.text().startswith("Plot area not changed"):
                self._say(f"The plot area is as shown{self._stand_text()}")
            return
        # Not saved, the fields go back to the area the map and figures show.
        if not self._still_shown(o.out, "The plot area"):
            self.area_row.show_area(o.area)
            return
        try:
            write_area(o.out, o.trees, self.review, area)
        except (AmrstError, OSError) as exc:
            self.area_row.show_area(o.area)
            self._say(f"Plot area not changed: {exc}", error=True)
            return
        self.shown_stamp = _stamp(o.out)
        self.found = replace(o, area=area)
        self._show_review()
        what = "No plot radius" if area is None else "Plot area changed"
        self._say(f"{what} (saved in {PLOT_JSON} and {TREES_CSV}){self._stand_text()}")

    def add_tree(self, x: float, y: float) -> None:
        """Add a tree the technician says stands at (x, y) m, or take back the added
        one not yet listed drawn there; saved in the review for the next run."""
        from amrst.plot.review import next_added_id, without_added

        self.trees.stop_adding()
        o = self.outcome
        if o is None:
            return
        near = self.stem_map.added_near(x, y)
        listed = self.stem_map.tree_near(x, y)
        if near is not None and near in self.stem_map.pending():
            review = without_added(self.review, near)
            done = f"{near} taken back"
        elif near is not None:
            self._say(
                f"{near} is listed: mark it Not a tree if none stands there.",
                error=True,
            )
            return
        elif listed is not None:
            self._say(
                f"{o.trees[listed].tree_id} stands there: a tree is listed once.",
                error=True,
            )
            return
        else:
            tree_id = next_added_id(self.review)
            review = replace(self.review, added={**self.review.added, tree_id: (x, y)})
            done = (
                f"{tree_id} added at {x:.1f}, {y:.1f} m: Run plot measures a tree there"
            )
        if self._save_review(review, "The tree"):
            self.stem_map.set_review(review)
            self._say(f"{done} (saved in {REVIEW_JSON})")

    def _review_trees(self, review: PlotReview, done: str, what: str) -> None:
        """Save a review of the trees, show it, and write the inventory with it."""
        from amrst.plot.export import TREES_CSV, write_inventory

        if not self._save_review(review, what):
            return
        o = self.outcome
        assert o is not None  # saved into its folder
        self._show_marks()
        try:
            write_inventory(o.out, o.trees, review, o.area, unsure=o.unsure)
        except FolderBusy as exc:
            self._say(
                f"{done}, saved in {REVIEW_JSON}; {TREES_CSV} not: {exc}", error=True
            )
            return
        except (AmrstError, OSError) as exc:
            self._say(
                f"{done}, saved in {REVIEW_JSON}; {TREES_CSV} was not written again "
                f"({exc}): close it where it is open, and try again.",
                error=True,
            )
            return
        self._say(
            f"{done} (saved in {REVIEW_JSON} and {TREES_CSV}){self._stand_text()}"
        )

    def toggle_accept(self) -> None:
        """Accept the selected link at its pose (asked first), or undo that."""
        from amrst.plot.export import TREES_CSV, write_states

        line = self.links.selected()
        if line is None or self.outcome is None:
            return
        name = f"S{line.target + 1}–S{line.source + 1}"
        accepted = dict(self.review.accepted)
        if line.status == ACCEPTED:
            del accepted[line.key]
            done = f"Link {name} needs review again"
        else:
            if line.status != NEEDS_REVIEW or line.T_world is None:
                return
            text = (
                f"Link {name} needs review: {line.message}\n\nAccept it at its pose? "
                "Do so only after checking it (Open pair: the overlay; each tree's "
                "slice here). The scans it places will read accepted."
            )
            if not confirm(self, "Accept the link?", text):
                return
            accepted[line.key] = line.T_world
            done = f"Link {name} accepted at its pose"
        if not self._save_review(replace(self.review, accepted=accepted), "The link"):
            return
        self._show_review()
        o = self.outcome
        assert o is not None
        try:
            write_states(
                o.out,
                [s.status for s in o.scans],
                {ln.key for ln in o.links if ln.status == ACCEPTED},
                o.trees,
                self.review,
                o.area,
            )
        except (AmrstError, OSError) as exc:
            self._say(
                f"{done}, saved in {REVIEW_JSON}; plot.json and {TREES_CSV} not: {exc}",
                error=True,
            )
            return
        self.shown_stamp = _stamp(o.out)
        self._say(
            f"{done} (saved in {REVIEW_JSON}, plot.json and {TREES_CSV}). "
            f"{self._summary()}"
        )

    def shutdown(self) -> None:
        """Drop a running plot or report (the main window closes)."""
        for job in (self.job, self.report_job):
            if job is not None:
                job.discard()
        self.job = self.report_job = None
        self.listing = self.opening = self.run_queued = False
        self._show_busy()

    # -------------------------------------------------------------- slots
    def _may_replace(self, out: Path) -> bool | None:
        """False: nothing to replace; True: replace (asked); None: keep it."""
        from amrst.plot.export import PLOT_CLOUD, PLOT_JSON, run_files
        from amrst.results.export import other_export

        if not (out / PLOT_JSON).exists():
            theirs = run_files(out) if out.is_dir() else []
            pair = other_export(out, []) if out.is_dir() else None
            if pair and not theirs:
                text = (
                    f"{out} holds {pair}: the plot's files go beside it, two "
                    "results in one folder. Go on?"
                )
                return True if confirm(self, "Write beside it?", text) else None
            if not theirs:
                return False
            text = (
                f"{out} holds {', '.join(theirs)} but no plot ({PLOT_JSON}): this run "
                "replaces or removes them. Go on?"
            )
            return True if confirm(self, "Replace those files?", text) else None
        what = {
            jobs.SAME_SCANS: "a plot of these scans (your review of it is kept)",
            jobs.SAME_REFERENCE: (
                "a plot of the same reference with other scans (your review of its "
                "trees is kept)"
            ),
        }.get(
            jobs.same_plot(out, self.scans.specs),
            "ANOTHER plot (another reference scan; its review no longer applies)",
        )
        text = f"{out} holds {what}. Replace its files with this run's?"
        if (out / PLOT_CLOUD).exists() and not self.cloud_check.isChecked():
            text += (
                f" Its {PLOT_CLOUD} is removed (tick {PLOT_CLOUD} to write it again)."
            )
        return True if confirm(self, "Replace the plot?", text) else None

    def _on_progress(self, fraction: float, message: str) -> None:
        self.progress.setValue(int(1000 * max(0.0, min(1.0, fraction))))
        if message:
            self._say(f"Running: {message}")

    def _on_result(self, outcome: PlotOutcome, opened: bool = False) -> None:
        self.job, self.opening = None, False
        self.found = outcome
        self._show_busy()
        self.shown_stamp = _stamp(outcome.out)
        if opened:
            self._take_scans(list(outcome.labels))
        self._shown_specs = list(self.scans.specs)
        self.area_row.show_area(outcome.area)
        # What placed each link carries on to the next run.
        left_out, hand_pairs, given = _run_choices(outcome)
        self.scans.set_given(given)
        self.links.set_choices(left_out, hand_pairs)
        try:
            review, self.review_error = read_review(outcome.out, outcome.labels), None
        except AmrstError as exc:
            review, self.review_error = PlotReview(), str(exc)
        self.review = review
        before, shown = self.outcome, self.stem_map.selected
        self.outcome = None
        self.stem_map.select(None)  # tree k of the last run is not tree k of this one
        self._show_review()
        self.tree_panel.show_tree(None, None, None)
        assert self.outcome is not None
        o = self.outcome
        unsure = bool(o.missing or o.labelled(NEEDS_REVIEW) or o.lost or o.no_tree_why)
        done = (
            f"opened from {o.out}"
            if opened
            else f"written to {o.out} in {o.seconds:.0f} s"
        )
        if o.lost:
            done += (
                f". No tree stands any more where you gave {', '.join(o.lost)}: "
                "dropped from your review"
            )
        gone = [s for s in o.labels if not scan_file_exists(s)]
        if gone:
            unsure = True
            done += (
                f". Not where plot.json says: {_numbered(o, gone)}; the plot shows from "
                "its results. To run it again, open the scans where they are now "
                "(File ▸ Open plot…) into this results folder: your review holds for "
                "the same files"
            )
        if self.review_error:
            done += f". Your review is not shown: {self.review_error}"
        self._say(f"{self._summary()}; {done}", error=unsure or bool(self.review_error))
        self.plot_done.emit(o)
        if not opened and before is not None and shown is not None:
            again = _same_tree(before, shown, o)
            if again is not None:
                self.select_tree(again)
        if self.run_queued:
            self.run_queued = False
            self.run()

    def _save_review(self, review: PlotReview, what: str) -> bool:
        """Write the review; keep it as the window's when written.

        Refused while a run goes on (it reads and writes the same file), and over a
        review.json that could not be read (it would lose what that file holds).
        """
        if self.busy or self.review_error:
            why = self.review_error or (
                "a plot is running into this folder; give it when the run has "
                "written its results."
            )
            self._say(f"{what} was not saved: {why}", error=True)
            return False
        o = self.outcome
        if o is None or not self._still_shown(o.out, what):
            return False
        try:
            write_review(o.out, o.labels, review)
        except (AmrstError, OSError) as exc:
            self._say(f"{what} was not saved: {exc}", error=True)
            return False
        self.review = review
        return True

    def _still_shown(self, out: Path, what: str) -> bool:
        """Tell whether ``out`` still holds the plot shown; say so when it does not."""
        if _stamp(out) == self.shown_stamp:
            return True
        self._say(
            f"{what} was not saved: the results in {out} changed since they were "
            "shown (another run wrote or removed them); open them again (File ▸ "
            "Open plot results…).",
            error=True,
        )
        return False

    def _summary(self) -> str:
        """The plot in a line: trees, scans by state, the bundle error; what to check."""
        from amrst.plot.register import HAND_ORIGIN

        o = self.outcome
        assert o is not None
        accepted = o.labelled(ACCEPTED)
        line = (
            f"{counted(len(o.trees), 'tree')}; {len(o.labelled(REGISTERED))} of "
            f"{len(o.scans)} scans registered"
            + (f", {len(accepted)} accepted by you" if accepted else "")
            + (
                f", bundle error {o.bundle_rmse_m * 100:.1f}{NBSP}cm"
                if math.isfinite(o.bundle_rmse_m)
                else ", no bundle error (no two scans placed together)"
            )
        )
        review, missing = o.labelled(NEEDS_REVIEW), o.missing
        if review:
            resting = seen_from_any(o.trees, o.unsure)
            line += (
                f". Needs review: {_numbered(o, review)}"
                + f" (check {'its' if len(review) == 1 else 'their'} links; "
                f"{counted(resting, 'tree')} seen from {'it' if len(review) == 1 else 'them'})"
            )
        if missing:
            line += (
                f". Not placed: {_numbered(o, missing)}"
                " (select its link, Open pair, pick point pairs, then Use pairs…)"
            )
        for k, scan in enumerate(o.scans):
            if scan.turned:
                line += f". S{k + 1} seems to stand {scan.turned}: export it z up"
        line += "".join(
            f". Your pairs of S{ln.target + 1}–S{ln.source + 1}: {ln.message}"
            for ln in o.links
            if ln.origin == HAND_ORIGIN and ln.status == NEEDS_REVIEW
        )
        if o.no_tree_why:
            line += f". No tree listed: {o.no_tree_why}"
        return line + self._stand_text()

    def _stand_text(self) -> str:
        """The stand per hectare with the review ("" without a plot radius)."""
        o = self.outcome
        if o is None or o.area is None:
            return ""
        st = stand(inventory_rows(o.trees, self.review, o.area, o.unsure), o.area)
        return ". W" + stand_line(st, o.area)[1:]

    def _on_report(self, path: Path) -> None:
        self.report_job = None
        self._update_tree_buttons()
        from amrst_gui import dialogs

        if dialogs.open_report(self, path):
            self._say(f"Report written and opened in the web browser: {path}")
        else:
            self._say(
                f"Report written: {path}. No web browser opened it; open the file by "
                "hand.",
                error=True,
            )

    def _on_report_error(self, exc: BaseException) -> None:
        self.report_job = None
        self._update_tree_buttons()
        text = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
        self._say(f"No report: {text.removeprefix('No report: ')}", error=True)

    def _on_error(self, exc: BaseException) -> None:
        listing, opening = self.listing, self.opening
        self.job = None
        self.listing = self.opening = self.run_queued = False
        self._show_busy()
        self._show_title()  # not "plot in" a folder that was not opened
        self.progress.setValue(0)
        if isinstance(exc, Cancelled):
            self._say(
                "Cancelled."
                if listing
                else "Opening cancelled."
                if opening
                else "Plot cancelled; nothing was written."
            )
            return
        text = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
        if listing or opening:
            self._say(f"Not opened: {text}", error=True)
            return
        if not isinstance(exc, AmrstError):
            log.error(
                "The plot failed:\n%s", getattr(exc, "__traceback_text__", repr(exc))
            )
        self._say(f"The plot failed: {text}", error=True)

    # ---------------------------------------------------------- showing
    def _show_review(self) -> None:
        """Show the run as the review leaves it: map, scans, links, marks."""
        assert self.found is not None
        selected = self.stem_map.selected
        self.outcome = jobs.reviewed(self.found, self.review.accepted)
        self.stem_map.set_plot(self.outcome)
        self.scans.show_lines(self.outcome)
        self.links.show_links(self.outcome)
        self._show_marks()
        if selected is not None:
            self.select_tree(selected)
        self._update_tree_buttons()

    def _show_marks(self) -> None:
        o = self.outcome
        if o is None:
            return
        k = self.stem_map.selected
        self.trees.show_trees(o, self.review, k)
        self.stem_map.set_review(self.review)
        if k is not None:
            self.tree_panel.show_tree(o, k, self.review)

    def _show_busy(self) -> None:
        """Enable what a job in progress (``busy``) and the plot shown (``found``)
        allow: called after every change of either, as the panels keep them."""
        self.run_button.setEnabled(not self.busy and len(self.scans.specs) >= 2)
        self.scans.set_state(self.busy, self.found is not None)
        self.cancel_button.setEnabled(self.busy)
        self.tree_panel.set_locked(self.busy)
        # A run or an opening ends by showing its plot's area in these fields.
        self.area_row.set_busy(self.busy)
        self.links.set_busy(self.busy)
        self._update_tree_buttons()

    def _update_tree_buttons(self) -> None:
        shown = self.outcome is not None and not self.busy
        self.trees.set_enabled(shown, self.report_job is None)

    def _say(self, text: str, error: bool = False) -> None:
        text = " ".join(text.splitlines())  # one line, whatever a path holds
        self.status.setText(text)
        self.status.setStyleSheet(ERROR_STYLE if error else "")
        (log.warning if error else log.info)("%s", text)

    def pending_choices(self) -> str:
        """Say what was chosen for the next run and not run yet ("" for nothing)."""
        o = self.found
        ran = o is not None and self._shown_specs == self.scans.specs
        then = _run_choices(o) if ran and o is not None else (set(), {}, {})
        now = (self.links.left_out, self.links.hand_pairs, self.scans.given_scanners)
        names = ("links left out", "links placed from point pairs", "scanner positions")
        return ", ".join(n for n, a, b in zip(names, now, then, strict=True) if a != b)

    def may_open_another(self) -> bool:
        """Ask before opening another plot drops a DBH being measured or what was
        chosen for the next run; True: open it.

        A hidden window asks nothing: closing it asked. Nor does a busy one: it
        refuses to open another, saying why.
        """
        from amrst_gui import dialogs

        if not self.isVisible() or self.busy:
            return True
        pending = self.pending_choices()
        lost = [self.tree_panel.unkept()]
        if pending:
            lost.append(
                f"the {pending} you chose for the next run (Run plot takes them)"
            )
        text = " and ".join(t for t in lost if t)
        return not text or dialogs.confirm_discard(self, "Opening another plot", text)

    def may_close(self) -> bool:
        """Ask before closing cancels a plot run, or drops a DBH being measured or
        what was chosen for the next run; True: close."""
        if self._close_agreed:
            return True
        text = (
            "A plot is running: closing the window cancels it. " if self.running else ""
        )
        if unkept := self.tree_panel.unkept():
            text += f"Closing the window drops {unkept}. "
        pending = self.pending_choices()
        if pending:
            text += (
                f"The {pending} you chose are not run yet: Run plot takes them; "
                "closing the window drops them. "
            )
        if text:
            self._close_agreed = ask_close(self, f"{text}Close it anyway?")
            return self._close_agreed
        return True

    def closeEvent(self, event) -> None:
        """Closing the window (asked first, :meth:`may_close`) cancels a running
        job."""
        if not self.may_close():
            event.ignore()
            return
        self._close_agreed = False
        self.shutdown()
        super().closeEvent(event)
