"""The Plot window's menu bar: its buttons, where a menu user looks for them.

Each item clicks its button, the one place that decides whether it may be used; the
item's text, enabled and checked state are the button's, read as its menu opens. A
key is the button's own shortcut (it works while the button may be used) and the item
only shows it: a key bound to both would fire neither.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from PySide6.QtGui import QAction, QKeySequence

from amrst.plot.review import NOT_A_TREE

if TYPE_CHECKING:
    from collections.abc import Callable

    from PySide6.QtWidgets import QAbstractButton, QMenu

    from amrst_gui.plot.window import PlotWindow


def build(window: PlotWindow) -> QMenu:
    """Fill ``window``'s menu bar: Plot, Scans, Links, Trees; return Plot."""
    bar = window.menuBar()
    plot = bar.addMenu("&Plot")
    _mirror(plot, window.choose_button, text="Choose results folder…")
    _mirror(plot, window.run_button, key="Ctrl+R", bind=True)
    _mirror(plot, window.cancel_button, key="Esc")
    plot.addSeparator()
    _mirror(plot, window.trees.report_button, text="Write report")
    _mirror(plot, window.trees.export_button, key="Ctrl+E", bind=True)
    plot.addSeparator()
    close = plot.addAction("Close")
    close.setShortcut(QKeySequence("Ctrl+W"))
    close.triggered.connect(window.close)

    scans = bar.addMenu("&Scans")
    for button in (
        window.scans.scanner_button,
        window.scans.reference_button,
        window.scans.remove_button,
    ):
        _mirror(scans, button)

    links = bar.addMenu("&Links")
    for button in (
        window.links.open_button,
        window.links.accept_button,
        window.links.pairs_button,
        window.links.leave_button,
    ):
        _mirror(links, button)

    trees = bar.addMenu("&Trees")
    for text, key, step in (("Next tree", "N", 1), ("Previous tree", "P", -1)):
        action = trees.addAction(f"{text}\t{key}")
        action.triggered.connect(lambda _=False, s=step: window.step_tree(s))
    trees.addSeparator()
    panel = window.tree_panel
    for mark, key in (("ok", "O"), ("check", "C"), (NOT_A_TREE, "X"), ("", "Del")):
        _mirror(
            trees, panel.buttons[mark], text=None if mark else "Clear mark", key=key
        )
    trees.addSeparator()
    _mirror(trees, window.trees.add_button)
    for button in (panel.measure_button, panel.keep_button, panel.forget_button):
        _mirror(trees, button)
    return plot


def add_open_actions(
    window: PlotWindow, open_plot: Callable[[], None], open_results: Callable[[], None]
) -> None:
    """Put the main window's Open plot… and Open plot results… first in Plot."""
    first = window.plot_menu.actions()[0]
    for text, slot in (("Open plot…", open_plot), ("Open plot results…", open_results)):
        action = QAction(text, window)
        action.triggered.connect(lambda _=False, s=slot: s())
        window.plot_menu.insertAction(first, action)
    window.plot_menu.insertSeparator(first)


def _mirror(
    menu: QMenu,
    button: QAbstractButton,
    *,
    text: str | None = None,
    key: str = "",
    bind: bool = False,
) -> QAction:
    """Add an item to ``menu`` that clicks ``button``.

    ``text`` replaces the button's (else its own, kept up to date); ``key`` is shown
    beside it, and with ``bind`` made the button's shortcut.
    """
    if bind:
        button.setShortcut(QKeySequence(key))
        button.setToolTip(f"{button.toolTip()} ({key})")
    action = QAction(menu)
    action.setCheckable(button.isCheckable())
    action.setToolTip(button.toolTip())

    def sync() -> None:
        label = text or button.text()
        action.setText(f"{label}\t{key}" if key else label)
        action.setEnabled(button.isEnabled())
        action.setChecked(button.isChecked())

    action.triggered.connect(lambda _=False: button.click())
    menu.aboutToShow.connect(sync)
    sync()
    menu.addAction(action)
    return action
