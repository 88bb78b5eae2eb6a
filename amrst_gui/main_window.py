"""MainWindow: docks, menus, toolbar around the 3D views; wires session to widgets."""

from __future__ import annotations

import importlib
import logging
from pathlib import Path
from typing import TYPE_CHECKING, cast

from PySide6.QtCore import QByteArray, Qt, QTimer
from PySide6.QtGui import QIcon
from PySide6.QtWidgets import (
    QDialog,
    QDockWidget,
    QFileDialog,
    QMainWindow,
    QMessageBox,
    QTabBar,
    QTabWidget,
)

from amrst.resources import resource_path
from amrst_gui import dialogs, menus
from amrst_gui.actions import WorkflowActions
from amrst_gui.app import app_settings, fit_screen
from amrst_gui.pacing import DRAWS
from amrst_gui.panels.campaign_panel import CampaignPanel
from amrst_gui.panels.log_panel import LogPanel
from amrst_gui.panels.manual_panel import ManualPanel
from amrst_gui.panels.matches_panel import MatchesPanel
from amrst_gui.panels.metrics_panel import MetricsPanel
from amrst_gui.panels.params_panel import ParamsPanel
from amrst_gui.panels.scans_panel import ScansPanel
from amrst_gui.panels.status import WorkflowStatusBar
from amrst_gui.session import Session
from amrst_gui.views.gl_warmup import warm_up_tabs
from amrst_gui.views.quality_views import StemSlicesPane
from amrst_gui.views.registration_pane import RegistrationPane
from amrst_gui.views.scan_pane import ScansArea

if TYPE_CHECKING:
    from amrst.campaign.stored import StoredLinkResult
    from amrst_gui.plot.window import PlotWindow

log = logging.getLogger("amrst_gui.main_window")

MAX_RECENT = 10

# Imported before the window shows: the GUI thread needs them when the first scans
# and results arrive (reading, candidates' rotations, the coarse choice), and a
# first import there would stall the window for a good part of a second.
EARLY_IMPORTS = ("laspy", "scipy.spatial.transform", "amrst.io", "amrst.pipeline")
LAYOUT_VERSION = 2  # 2: the Manual pose dock, full-height side docks


class MainWindow(QMainWindow):
    """The app window. Owns the Session; every panel and view listens to it.

    Listens to ``failed`` (status bar, log, non-blocking message), ``scan_loaded``
    (recent files, title) and ``busy_changed``; the panels and views listen to
    the rest (see their docstrings).
    """

    # The window's WorkflowActions. The name shadows QWidget.actions() on every
    # MainWindow (menus and tests use it): call QWidget.actions(window) for Qt's list.
    actions: WorkflowActions  # type: ignore[assignment]

    def __init__(self, session: Session | None = None, settings=None) -> None:
        for name in EARLY_IMPORTS:
            importlib.import_module(name)
        super().__init__()
        self.setObjectName("main_window")
        self.setWindowTitle("AMRST Studio")
        self.setWindowIcon(QIcon(str(resource_path("icons", "amrst.svg"))))
        self.settings = settings if settings is not None else app_settings()
        # The log first, so it records everything from here on.
        self.log_panel = LogPanel()
        self.session = session if session is not None else Session(self)
        s = self.session
        self.scans_area = ScansArea(s)
        self.registration = RegistrationPane(s)
        self.tabs = QTabWidget()
        self.tabs.setObjectName("view_tabs")
        self.tabs.addTab(self.scans_area, "Scans: target | source")
        self.tabs.addTab(self.registration, "Registration overlay")
        self.slices = StemSlicesPane(s)
        self.tabs.addTab(self.slices, "Stem slices")
        self.setCentralWidget(self.tabs)
        self.actions = WorkflowActions(self, s)
        self._build_docks(s)
        self.status = WorkflowStatusBar(s, self)
        self.setStatusBar(self.status)
        self.toolbar = menus.build(self)
        self.error_box: QMessageBox | None = None
        self.export_box: dialogs.ExportDialog | None = None
        self.plot_window: PlotWindow | None = None  # made when a plot is opened
        self._closed = False
        self._close_when_idle = False  # a close waits for a job that writes files
        self._connect(s)
        self._fit_screen()
        self._default_state: QByteArray | None = None
        self._restored = self._restore_settings()
        self.scans_area.refresh()
        self.registration.refresh()

    # ----------------------------------------------------------- building
    def _build_docks(self, s: Session) -> None:
        """The panels, each in a dock: Scans, Parameters and Campaign on the left,
        Matches, Metrics and Manual pose on the right, the Log at the bottom."""
        self.scans_panel = ScansPanel(s)
        self.params_panel = ParamsPanel(s)
        self.matches_panel = MatchesPanel(s, self.actions.reject, self.actions.restore)
        self.metrics_panel = MetricsPanel(s)
        self.manual_panel = ManualPanel(
            s,
            self.scans_area.panes["target"].view,
            self.scans_area.panes["source"].view,
        )
        self.docks: dict[str, QDockWidget] = {}
        left, right, bottom = (
            Qt.DockWidgetArea.LeftDockWidgetArea,
            Qt.DockWidgetArea.RightDockWidgetArea,
            Qt.DockWidgetArea.BottomDockWidgetArea,
        )
        self._add_dock("scans", "Scans", self.scans_panel, left)
        self._add_dock("parameters", "Parameters", self.params_panel, left)
        self._add_dock("matches", "Matches", self.matches_panel, right)
        self._add_dock("metrics", "Metrics", self.metrics_panel, right)
        self._add_dock("manual", "Manual pose", self.manual_panel, right)
        self.tabifyDockWidget(self.docks["metrics"], self.docks["manual"])
        self.docks["metrics"].raise_()
        self.manual_panel.pick_button.toggled.connect(self._make_room_for_picking)
        self._heights_before_picking: list[int] | None = None
        self._add_dock("log", "Log", self.log_panel, bottom)
        self.campaign_panel = CampaignPanel(self)  # a tree's scans open as the pair
        self._add_dock("campaign", "Campaign", self.campaign_panel, left)
        self.campaign_panel.link_chosen.connect(self._show_campaign_link)
        # A campaign link chosen while scans are read is shown when they are.
        self._pending_link: tuple[str, str, StoredLinkResult | None] | None = None
        s.busy_changed.connect(self._show_pending_link)
        s.cancelled.connect(self._drop_pending_link)  # Esc drops what waited too
        self.tabifyDockWidget(self.docks["scans"], self.docks["parameters"])
        self.tabifyDockWidget(self.docks["scans"], self.docks["campaign"])
        # The side docks run the full height: the log sits under the views only, so
        # the Matches table keeps its rows on a laptop screen.
        self.setCorner(Qt.Corner.BottomRightCorner, right)
        self.setCorner(Qt.Corner.BottomLeftCorner, left)
        self.docks["scans"].raise_()

    def _connect(self, s: Session) -> None:
        """The session's signals to the window, the panels' requests to the session."""
        s.discard_guard = lambda action, lost, keep: dialogs.confirm_discard(
            self, action, lost, keep
        )
        s.failed.connect(self._on_failed)
        # After Accept coarse, Fine or Run all the result is what to look at.
        s.coarse_accepted.connect(self._show_overlay)
        s.fine_finished.connect(self._show_overlay)
        s.scan_loaded.connect(self._on_scan_loaded)
        s.scans_swapped.connect(self._update_title)
        self.params_panel.params_applied.connect(s.set_params)
        self.scans_panel.open_requested.connect(self.open_scan_dialog)
        self.scans_panel.recent_chosen.connect(
            lambda role, path: s.load_scan(role, path)
        )
        self.scans_panel.swap_requested.connect(s.swap_scans)
        self.scans_panel.files_dropped.connect(self._on_files_dropped)
        self.scans_area.files_dropped.connect(self._on_files_dropped)

    def _fit_screen(self) -> None:
        """Open at 1500x950, or maximised on a smaller screen."""
        fit_screen(self, 1500, 950)

    # ------------------------------------------------------------- public
    def views(self) -> list:
        """Every ScanView (closed explicitly when the window closes)."""
        return [*self.scans_area.views(), self.registration.view]

    def open_pair(self, target, source, truth=None) -> None:
        """Load a target and a source (in a worker), and a truth file if given."""
        # Scans first: a truth loaded before them would belong to the old pair.
        self.session.load_scans(target, source)
        if truth is not None:
            self.session.load_truth(truth)

    def recent_files(self) -> list[str]:
        """Recently opened scan files that still exist, newest first."""
        value = self.settings.value("recent/files", [])
        # value() is typed object; here a str, a list of str, or None or [] if unset.
        paths = (
            [value] if isinstance(value, str) else list(cast("list[str]", value or []))
        )
        return [p for p in paths if Path(p).is_file()]  # moved or deleted: not offered

    def reset_layout(self) -> None:
        """Put every dock back where it started."""
        if self._default_state is not None:
            self.restoreState(self._default_state)
        for dock in self.docks.values():
            dock.show()
        QTimer.singleShot(0, self, self._hide_stray_tab_bars)

    # ------------------------------------------------------------ dialogs
    def open_scan_dialog(self, role: str) -> None:
        """Ask for a scan file for ``role``."""
        from amrst import io

        patterns = " ".join(f"*{ext}" for ext in io.supported_extensions())
        start = str(self.settings.value("dirs/open", "", type=str) or Path.home())
        path, _ = QFileDialog.getOpenFileName(
            self,
            f"Open the {role} scan",
            start,
            f"Point clouds ({patterns});;All files (*)",
        )
        if path:
            self.settings.setValue("dirs/open", str(Path(path).parent))
            self.session.load_scan(role, path)

    def open_scan_dialog_target(self) -> None:
        self.open_scan_dialog("target")

    def open_scan_dialog_source(self) -> None:
        self.open_scan_dialog("source")

    def open_truth_dialog(self) -> None:
        """Ask for a truth.json."""
        start = str(self.settings.value("dirs/open", "", type=str) or Path.home())
        path, _ = QFileDialog.getOpenFileName(
            self, "Load truth", start, "Truth (*.json)"
        )
        if path:
            self.session.load_truth(path)

    def load_params_dialog(self) -> None:
        """Read parameters from JSON and use them."""
        dialogs.load_params(self)

    def save_params_dialog(self) -> None:
        """Write the current parameters to JSON."""
        dialogs.save_params(self)

    def export_dialog(self) -> dialogs.ExportDialog:
        """Open the export dialog (non-blocking); Export starts the job."""
        folder = self.settings.value("dirs/export", "")
        fmt = self.settings.value("export/format", "ply")
        target = self.session.path("target")
        base = target.parent if target is not None else None
        box = dialogs.ExportDialog(
            self, folder=str(folder), cloud_format=str(fmt), base=base
        )
        box.accepted.connect(lambda: self._on_export_accepted(box))
        self.export_box = box
        box.open()
        return box

    def view_report(self) -> None:
        """Open the last export's report.html in the web browser."""
        path = self.session.last_report
        if path is None or not path.is_file():
            self.status.show_message(
                "No report yet: Export (Ctrl+E) writes report.html with the files.",
                error=True,
            )
            return
        if dialogs.open_report(self, path):
            self.status.show_message(f"Opened {path.name} in the web browser.")
        else:
            self.status.show_message(
                f"No web browser opened {path}; open the file by hand.", error=True
            )

    # --------------------------------------------------------------- plot
    def open_plot_dialog(self) -> None:
        """Ask for a plot's scans (the first by name is the reference); open them."""
        from amrst_gui.plot.window import ask_scans

        paths = ask_scans(self, self.settings)
        if paths:
            self.open_plot(paths)

    def open_plot(self, paths: list, out: Path | None = None) -> PlotWindow:
        """Show the Plot window with these scans (and results folder, if given),
        asked first when that drops work on the plot it shows."""
        plot = self._plot_window()
        if plot.may_open_another():
            plot.open_scans(paths, out)
        plot.show()
        plot.raise_()
        return plot

    def open_plot_results_dialog(self) -> None:
        """Ask for a plot's results folder; show the plot it holds."""
        from PySide6.QtWidgets import QFileDialog

        folder = QFileDialog.getExistingDirectory(
            self, "A plot's results folder (it holds plot.json)", str(Path.home())
        )
        if folder:
            self.open_plot_results(Path(folder))

    def open_plot_results(self, out: Path) -> PlotWindow:
        """Show the Plot window with the plot ``out`` holds (no run), asked first
        when that drops work on the plot it shows."""
        plot = self._plot_window()
        if plot.may_open_another():
            plot.open_results(out)
        plot.show()
        plot.raise_()
        return plot

    def _plot_window(self) -> PlotWindow:
        """The Plot window, made the first time."""
        from amrst_gui.plot import menus
        from amrst_gui.plot.window import PlotWindow

        if self.plot_window is None:
            self.plot_window = PlotWindow(self)  # a window of its own
            self.plot_window.open_pair_in = self.open_plot_pair
            menus.add_open_actions(
                self.plot_window, self.open_plot_dialog, self.open_plot_results_dialog
            )
        return self.plot_window

    def open_plot_pair(
        self, target: str, source: str, stored: StoredLinkResult | None
    ) -> str:
        """Open two scans of the plot at their link's pose (``stored``; None: none),
        the Manual pose dock in front; return "" or why they are not opened."""
        why = self.session.load_stored(target, source, stored, plot=True)
        if why:
            return why
        self.docks["manual"].show()
        self.docks["manual"].raise_()
        self.raise_()
        self.activateWindow()
        return ""

    def _show_campaign_link(
        self, target: str, source: str, stored: StoredLinkResult | None
    ) -> None:
        """Show a campaign tree's link at its stored pose (no registration).

        Chosen while other scans are being read (a tree clicked, then the next), it
        waits for them: the views always end on the tree last chosen.
        """
        self._pending_link = None
        if self.session.running_step == "load":
            self._pending_link = (target, source, stored)
            return
        if self.session.load_stored(target, source, stored):  # declined, or busy
            self._keep_campaign_shown()

    def _drop_pending_link(self, *_args) -> None:
        if self._pending_link is not None:
            self._pending_link = None
            self._keep_campaign_shown()

    def _keep_campaign_shown(self) -> None:
        """The Campaign dock selects again the tree the views show."""
        s = self.session
        self.campaign_panel.keep_shown(s.path("target"), s.path("source"))

    def _show_pending_link(self, busy: bool) -> None:
        if not busy and self._pending_link is not None:
            self._show_campaign_link(*self._pending_link)

    def about_dialog(self) -> None:
        dialogs.AboutDialog(self).open()

    def shortcuts_dialog(self) -> None:
        dialogs.ShortcutsDialog(menus.all_actions(self), self).open()

    # -------------------------------------------------------------- slots
    def _on_export_accepted(self, box: dialogs.ExportDialog) -> None:
        self.settings.setValue("dirs/export", str(box.folder()))
        self.settings.setValue("export/format", box.cloud_format())
        verdict = self.session.verdict
        override = False
        if verdict is not None and not verdict.ok:
            # A result that is not "registered" leaves only on purpose.
            if not dialogs.confirm_override(self, verdict):
                self.status.show_message("Export cancelled: " + verdict.text())
                return
            override = True
        self.session.export(
            box.folder(), box.cloud_format(), box.parts(), override=override
        )

    def _show_overlay(self, *_args) -> None:
        # In its own turn: the overlay's first frame is a stall of its own, not
        # added to the panels' work on the same result.
        DRAWS.later(self, "overlay", self._show_overlay_now)

    def _show_overlay_now(self) -> None:
        # Not once the views are closing: showing a closed view would paint it.
        if not (self._closed or self.registration.view.closed):
            self.tabs.setCurrentWidget(self.registration)

    def _on_failed(self, message: str) -> None:
        # Status bar and log show it too; the box does not block the window.
        if self.error_box is not None and self.error_box.isVisible():
            self.error_box.setText(message)
            return
        box = QMessageBox(
            QMessageBox.Icon.Warning,
            "AMRST Studio",
            message,
            QMessageBox.StandardButton.Ok,
            self,
        )
        box.setObjectName("error_box")
        box.setWindowModality(Qt.WindowModality.NonModal)
        box.show()
        self.error_box = box

    def _on_scan_loaded(self, role: str) -> None:
        path = self.session.path(role)
        if path is not None:
            recent = [str(path)] + [p for p in self.recent_files() if p != str(path)]
            self.settings.setValue("recent/files", recent[:MAX_RECENT])
            self.scans_panel.set_recent_files(self.recent_files())
        self._update_title()

    def _update_title(self) -> None:
        names = [self.session.path(r) for r in ("target", "source")]
        label = " ← ".join(p.name if p else "-" for p in names)
        self.setWindowTitle(f"AMRST Studio: {label}")

    def _on_files_dropped(self, role: str, paths: list) -> None:
        """Scans open in their roles; a dropped ``.json`` is the pair's truth."""
        truths = [p for p in paths if Path(p).suffix.lower() == ".json"]
        paths = [p for p in paths if p not in truths]
        if len(truths) > 1:
            log.warning(
                "%d JSON files dropped: only one can be the truth; none is loaded.",
                len(truths),
            )
        truth = truths[0] if len(truths) == 1 else None
        if not paths:
            if truth is not None:
                self.session.load_truth(truth)
            return
        if len(paths) > 2:
            log.warning(
                "%d files dropped: the first two are opened as target and source; "
                "ignored: %s",
                len(paths),
                ", ".join(Path(p).name for p in paths[2:]),
            )
        if len(paths) >= 2:
            self.open_pair(paths[0], paths[1], truth)
        else:
            self.session.load_scan(role, paths[0])
            if truth is not None:  # after the scan: it belongs to the new pair
                self.session.load_truth(truth)

    # ----------------------------------------------------------- plumbing
    def _add_dock(self, key: str, title: str, widget, area) -> QDockWidget:
        dock = QDockWidget(title, self)
        dock.setObjectName(f"{key}_dock")  # saveState needs it
        dock.setWidget(widget)
        dock.setFeatures(
            QDockWidget.DockWidgetFeature.DockWidgetMovable
            | QDockWidget.DockWidgetFeature.DockWidgetFloatable
            | QDockWidget.DockWidgetFeature.DockWidgetClosable
        )
        self.addDockWidget(area, dock)
        self.docks[key] = dock
        for moved in (dock.dockLocationChanged, dock.topLevelChanged):
            moved.connect(
                lambda *_: QTimer.singleShot(0, self, self._hide_stray_tab_bars)
            )
        return dock

    def _restore_settings(self) -> bool:
        geometry = self.settings.value("window/geometry")
        state = self.settings.value("window/state")
        if isinstance(geometry, QByteArray):
            self.restoreGeometry(geometry)
        # A layout saved before the docks changed is not restored (Qt would leave the
        # new docks floating about): the version says which docks the state knows.
        restored = isinstance(state, QByteArray) and self.restoreState(
            state, LAYOUT_VERSION
        )
        self.scans_panel.set_recent_files(self.recent_files())
        return bool(restored)

    def showEvent(self, event) -> None:
        """Size the docks once the window has its size (only then does Qt apply it)."""
        super().showEvent(event)
        if self._default_state is None:
            if not self._restored:
                self._default_sizes()
            self._default_state = self.saveState()
            QTimer.singleShot(0, self.tabs, self._warm_up_views)
        QTimer.singleShot(0, self, self._hide_stray_tab_bars)

    def _hide_stray_tab_bars(self) -> None:
        """Hide the dock tab bars Qt leaves drawn over the docks after a layout change.

        Qt 6 keeps the tab bar of a tab group it rebuilt visible where it was; the one
        in use lies along the edge of its current dock, a stray one does not.
        """
        docks = {d.windowTitle(): d for d in self.docks.values()}
        for bar in self.findChildren(
            QTabBar, options=Qt.FindChildOption.FindDirectChildrenOnly
        ):
            if bar.isHidden():
                continue
            dock = docks.get(bar.tabText(bar.currentIndex()))
            if dock is None or dock.isFloating() or not _along(bar, dock):
                bar.hide()

    def _warm_up_views(self) -> None:
        """Set OpenGL up in the other tabs' views before any scan (gl_warmup)."""
        if self.isVisible() and not self._closed:
            warm_up_tabs(self.tabs, self.views())

    def _make_room_for_picking(self, on: bool) -> None:
        """Give the Manual pose dock most of the right column while pairs are
        picked (its pair table and Nudge, not the Matches table, are in use), and
        hand the room back after."""
        pair = [self.docks["matches"], self.docks["manual"]]
        vertical = Qt.Orientation.Vertical
        closed = not all(d.toggleViewAction().isChecked() for d in pair)
        if (
            closed
            or any(d.isFloating() for d in pair)
            or len({self.dockWidgetArea(d) for d in pair}) > 1
        ):
            return  # the technician's own layout: left as it is
        if on and self._heights_before_picking is None:
            self._heights_before_picking = [d.height() for d in pair]
            total = sum(self._heights_before_picking)
            self.resizeDocks(pair, [total * 3 // 10, total * 7 // 10], vertical)
        elif not on and self._heights_before_picking is not None:
            self.resizeDocks(pair, self._heights_before_picking, vertical)
            self._heights_before_picking = None

    def _default_sizes(self) -> None:
        d = self.docks
        self.resizeDocks(
            [d["scans"], d["matches"]], [330, 430], Qt.Orientation.Horizontal
        )
        self.resizeDocks(
            [d["matches"], d["metrics"]], [55, 45], Qt.Orientation.Vertical
        )
        self.resizeDocks([d["log"]], [120], Qt.Orientation.Vertical)

    def closeEvent(self, event) -> None:
        """Cancel a running step and wait for it, save the layout, close the views.

        An Export writing its files runs to its end: it is not waited for here,
        with the window frozen; the close comes again once it has ended (and asks
        then what the window asks). An Export still waiting for the engine is
        cancelled as any job.
        """
        if not self._closed and self.session.runner.writing:
            if not self._close_when_idle:
                self._close_when_idle = True
                self.session.busy_changed.connect(self._close_once_idle)
            self.status.show_message("Closing once Export has written its files…")
            event.ignore()
            return
        if not self._closed and not (
            self.session.may_discard("Closing AMRST Studio")
            and (
                self.plot_window is None
                or not self.plot_window.isVisible()
                or self.plot_window.may_close()
            )
        ):
            event.ignore()
            return
        if not self._closed:
            self._closed = True
            if self.session.busy:
                self.status.show_message("Cancelling the running step…")
            self.scans_panel.close_jobs()  # a description would hold the close
            # Every job is cancelled before the wait for the worker threads: a plot
            # or a batch still running would hold the close until it ended.
            self.campaign_panel.shutdown()
            if self.plot_window is not None:
                self.plot_window.close()
            self.session.shutdown()
            self.settings.setValue("window/geometry", self.saveGeometry())
            self.settings.setValue("window/state", self.saveState(LAYOUT_VERSION))
            self.settings.sync()
            self.log_panel.detach()
            for dock in self.docks.values():  # floating docks are windows of their own
                if dock.isFloating():
                    dock.hide()
            for dialog in self.findChildren(QDialog):  # messages, export, about
                dialog.close()
            # Before the widgets go: VTK must not outlive them.
            for view in self.views():
                view.close_view()
        super().closeEvent(event)

    def _close_once_idle(self, busy: bool) -> None:
        if busy:
            return
        self.session.busy_changed.disconnect(self._close_once_idle)
        self._close_when_idle = False
        QTimer.singleShot(0, self.close)  # after the job's result was applied


def _along(bar: QTabBar, dock: QDockWidget) -> bool:
    """Whether ``bar`` lies along the top or bottom edge of ``dock`` (2 px slack)."""
    b, d = bar.geometry(), dock.geometry()
    overlaps = b.left() < d.right() and d.left() < b.right()
    touches = abs(b.top() - d.bottom() - 1) <= 2 or abs(d.top() - b.bottom() - 1) <= 2
    return overlaps and touches
