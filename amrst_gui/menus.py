"""The menu bar and the workflow toolbar, built from WorkflowActions."""

from __future__ import annotations

from PySide6.QtCore import Qt
from PySide6.QtWidgets import QToolBar


def build(window) -> QToolBar:
    """Fill the window's menu bar; add and return the workflow toolbar."""
    a = window.actions
    bar = window.menuBar()
    file_menu = bar.addMenu("&File")
    for action in (a.open_target, a.open_source, a.swap, a.load_truth):
        file_menu.addAction(action)
    file_menu.addAction("Cut a &tree from a plot file…", lambda: _clip_dialog(window))
    file_menu.addAction("Open &plot…", window.open_plot_dialog)
    file_menu.addAction("Open plot r&esults…", window.open_plot_results_dialog)
    file_menu.addSeparator()
    file_menu.addAction(a.load_params)
    file_menu.addAction(a.save_params)
    file_menu.addSeparator()
    file_menu.addAction(a.export)
    file_menu.addAction(a.view_report)
    file_menu.addSeparator()
    file_menu.addAction(a.quit)

    flow = bar.addMenu("&Workflow")
    for action in a.step_actions.values():
        flow.addAction(action)
    flow.addSeparator()
    flow.addAction(a.run_all)
    flow.addAction(a.cancel)

    review = bar.addMenu("&Review")
    review.addAction(a.reject)
    review.addAction(a.restore)

    view = bar.addMenu("&View")
    for dock in window.docks.values():
        view.addAction(dock.toggleViewAction())
    view.addSeparator()
    view.addAction("Reset &layout", window.reset_layout)
    view.addAction("Reset &cameras", window.scans_area.reset_cameras)

    help_menu = bar.addMenu("&Help")
    help_menu.addAction(a.shortcuts)
    help_menu.addAction(a.about)

    toolbar = QToolBar("Workflow", window)
    toolbar.setObjectName("workflow_toolbar")  # saveState needs it
    toolbar.setToolButtonStyle(Qt.ToolButtonStyle.ToolButtonTextBesideIcon)
    toolbar.addAction(a.open_target)
    toolbar.addAction(a.open_source)
    toolbar.addSeparator()
    for action in a.step_actions.values():
        toolbar.addAction(action)
    toolbar.addSeparator()
    toolbar.addAction(a.run_all)
    toolbar.addAction(a.export)
    toolbar.addAction(a.cancel)
    window.addToolBar(Qt.ToolBarArea.TopToolBarArea, toolbar)
    # Shortcuts must work even when the menu bar is hidden or the toolbar floats.
    for action in all_actions(window):
        if action.shortcutContext() != Qt.ShortcutContext.WidgetWithChildrenShortcut:
            window.addAction(action)
    return toolbar


def all_actions(window) -> list:
    """Every action of the window, in menu order."""
    a = window.actions
    return [
        a.open_target,
        a.open_source,
        a.swap,
        a.load_truth,
        a.load_params,
        a.save_params,
        *a.step_actions.values(),
        a.run_all,
        a.cancel,
        a.export,
        a.reject,
        a.restore,
        a.shortcuts,
        a.about,
        a.quit,
    ]


def _clip_dialog(window) -> None:
    from amrst_gui.clip_dialog import ClipDialog

    ClipDialog(window.session, window).open()
