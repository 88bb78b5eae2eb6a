"""WorkflowActions: every QAction of the window, their shortcuts and their state."""

from __future__ import annotations

from PySide6.QtCore import QObject, Qt
from PySide6.QtGui import QAction, QKeySequence
from PySide6.QtWidgets import QStyle

from amrst_gui import steps

# What the engine's step table (amrst.pipeline.steps.STEPS) does not say about a
# step's action: its attribute name here, icon and what it does. The actions are made
# for every step of the table, in its order, with Ctrl+1, Ctrl+2, ...; a step without
# an entry gets an action named after it.
_STEP_EXTRAS = {
    "separate": (
        "separate",
        None,
        "Preprocess both scans and separate wood (brown) from leaves (green).",
    ),
    "skeleton": (
        "skeleton",
        None,
        "Build each tree's skeleton from its wood points and pick the key points.",
    ),
    "match": (
        "match",
        None,
        "Find similar tetrahedra between the key points and rank them (runs the "
        "earlier steps first when they are missing or stale).",
    ),
    "coarse": (
        "accept_coarse",
        QStyle.StandardPixmap.SP_DialogApplyButton,
        "Accept the candidate shown in the Matches list (its selected row; the best "
        "one you did not reject when none is selected).",
    ),
    "fine": (
        "run_fine",
        None,
        "Refine the accepted coarse solution with ICP and measure the result.",
    ),
}
# Steps that need more than the scans to start (else: enabled once both are loaded).
_READY = {
    "coarse": lambda s: s.coarse is not None,
    "fine": lambda s: s.accepted_coarse is not None,
}


class WorkflowActions(QObject):
    """The window's actions; enabled state and labels follow the session.

    Listens to ``busy_changed``, ``params_changed``, ``review_changed`` and the
    result signals; ``(stale)`` marks a step whose parameters changed since it ran.
    Triggers session methods directly, and window methods for anything with a dialog.
    """

    # Set with setattr from the step table in __init__; declared here for mypy.
    separate: QAction
    skeleton: QAction
    match: QAction
    accept_coarse: QAction
    run_fine: QAction

    def __init__(self, window, session) -> None:
        super().__init__(window)
        self.window = window
        self.session = session
        style = window.style()
        self.open_target = self._make(
            "Open &target…",
            "Ctrl+O",
            window.open_scan_dialog_target,
            "Choose the reference scan",
            style.standardIcon(QStyle.StandardPixmap.SP_DialogOpenButton),
        )
        self.open_source = self._make(
            "Open &source…",
            "Ctrl+Shift+O",
            window.open_scan_dialog_source,
            "Choose the scan to move onto the target",
        )
        self.load_truth = self._make(
            "Load &truth…",
            "Ctrl+T",
            window.open_truth_dialog,
            "Read a truth.json (T_target_source) to show the true errors",
        )
        self.swap = self._make(
            "S&wap target and source",
            "Ctrl+Shift+X",  # not Ctrl+W, which closes windows in most apps
            session.swap_scans,
            "Make the source the reference (clears the results)",
        )
        self.load_params = self._make(
            "&Load parameters…",
            "",
            window.load_params_dialog,
            "Read parameters from a params.json",
        )
        self.save_params = self._make(
            "Sa&ve parameters…",
            "Ctrl+S",
            window.save_params_dialog,
            "Write the current parameters to a JSON file",
        )
        self.quit = self._make(
            "&Quit", QKeySequence.StandardKey.Quit, window.close, "Close AMRST Studio"
        )
        self.step_actions: dict[str, QAction] = {}
        for number, step in enumerate(steps.STEPS, start=1):
            attr, icon, tip = _STEP_EXTRAS.get(
                step, (step, None, steps.plain_label(step))
            )
            # Accept coarse takes the selected row: the session method, not the step.
            run = (
                session.accept_coarse
                if step == "coarse"
                else lambda _=False, s=step: session.run_step(s)
            )
            action = self._make(
                steps.LABELS[step],
                f"Ctrl+{number}",
                run,
                tip,
                style.standardIcon(icon) if icon else None,
            )
            setattr(self, attr, action)
            self.step_actions[step] = action
        self.find_matches = self.match  # the name of the step's engine function
        self.run_all = self._make(
            "Run &all",
            "Ctrl+R",
            session.run_all,
            "The automatic path: every step up to fine registration, "
            "accepting the best candidate",
            style.standardIcon(QStyle.StandardPixmap.SP_MediaPlay),
        )
        self.export = self._make(
            "&Export…",
            "Ctrl+E",
            window.export_dialog,
            "Write the registered source, merged cloud, transform, "
            "metrics and parameters",
            style.standardIcon(QStyle.StandardPixmap.SP_DialogSaveButton),
        )
        self.view_report = self._make(
            "View &report",
            "",
            window.view_report,
            "Open the report the last export wrote (report.html) in your web browser",
        )
        self.cancel = self._make(
            "&Cancel",
            "Esc",
            session.cancel,
            "Stop the running step; earlier results are kept",
            style.standardIcon(QStyle.StandardPixmap.SP_BrowserStop),
        )
        # Review keys act only while the Matches dock has focus (typing is safe).
        self.reject = self._make(
            "&Reject match",
            QKeySequence.StandardKey.Delete,
            self._reject_selected,
            "Exclude the selected match from the coarse solution (Del)",
        )
        self.restore = self._make(
            "Re&store match",
            "R",
            self._restore_selected,
            "Use the selected match again (R)",
        )
        for action in (self.reject, self.restore):
            action.setShortcutContext(Qt.ShortcutContext.WidgetWithChildrenShortcut)
        self.about = self._make(
            "&About AMRST Studio",
            "",
            window.about_dialog,
            "Versions of AMRST and of the libraries it uses",
        )
        self.shortcuts = self._make(
            "&Keyboard shortcuts",
            "F1",
            window.shortcuts_dialog,
            "List the keyboard shortcuts",
        )
        for name in (
            "busy_changed",
            "params_changed",
            "review_changed",
            "selection_changed",
            "scan_loaded",
            "scans_swapped",
            "separation_finished",
            "skeletons_finished",
            "matches_changed",
            "coarse_accepted",
            "fine_finished",
            "exported",
        ):
            getattr(session, name).connect(self._on_session_changed)
        self.refresh()

    def job_actions(self) -> list[QAction]:
        """Actions that start a job (disabled while one runs)."""
        return [*self.step_actions.values(), self.run_all, self.export]

    def refresh(self) -> None:
        """Enable, disable and relabel the actions from the session's state."""
        s = self.session
        idle = not s.busy
        for action in (
            self.open_target,
            self.open_source,
            self.load_params,
            self.load_truth,
        ):
            action.setEnabled(idle)
        self.swap.setEnabled(idle and s.has_scans)
        for step, action in self.step_actions.items():
            action.setText(self._label(step))
            action.setToolTip(self._tooltip(step, action.statusTip()))
        for step, action in self.step_actions.items():
            ready = _READY.get(step, lambda s: s.has_scans)
            action.setEnabled(idle and bool(ready(s)))
        self.run_all.setEnabled(idle and s.has_scans)
        # A result the review or the parameters left behind is not offered for export;
        # the tooltip says what to run first.
        stale = s.out_of_date if s.final_transform is not None else ""
        self.export.setEnabled(idle and s.final_transform is not None and not stale)
        self.export.setToolTip(stale or self.export.statusTip())
        self.view_report.setEnabled(s.last_report is not None)
        self.cancel.setEnabled(s.busy)
        selected = s.selected_match
        self.reject.setEnabled(selected is not None and selected.id not in s.rejected)
        self.restore.setEnabled(selected is not None and selected.id in s.rejected)

    def _label(self, step: str) -> str:
        base = steps.LABELS[step]
        if self.session.is_stale(step):
            return f"{base} (stale)"
        if self.session.is_done(step):
            return f"{base} ✓"
        return base

    def _tooltip(self, step: str, what: str) -> str:
        shortcut = (
            self.step_actions[step]
            .shortcut()
            .toString(QKeySequence.SequenceFormat.NativeText)
        )
        if self.session.is_stale(step):
            state = "Its parameters or inputs changed since it ran: run it again."
        elif self.session.is_done(step):
            state = "Done."
        else:
            state = "Not run yet."
        return f"{what} ({shortcut})\n{state}"

    def _make(self, text, shortcut, slot, tip: str = "", icon=None) -> QAction:
        action = QAction(text, self.window)
        if icon is not None:
            action.setIcon(icon)
        if shortcut:
            action.setShortcut(QKeySequence(shortcut))
        action.setStatusTip(tip)
        action.setToolTip(tip)
        action.triggered.connect(lambda _=False: slot())
        return action

    def _reject_selected(self) -> None:
        cand = self.session.selected_match
        if cand is not None:
            self.session.reject_match(cand.id)

    def _restore_selected(self) -> None:
        cand = self.session.selected_match
        if cand is not None:
            self.session.restore_match(cand.id)

    def _on_session_changed(self, *_args) -> None:
        self.refresh()
