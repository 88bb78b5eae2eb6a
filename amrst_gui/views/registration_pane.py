"""RegistrationPane: target and moved source overlaid, before / coarse / fine."""

from __future__ import annotations

from PySide6.QtWidgets import (
    QButtonGroup,
    QHBoxLayout,
    QLabel,
    QRadioButton,
    QVBoxLayout,
    QWidget,
)

from amrst_gui.views.scan_pane import RESULT_SIGNALS
from amrst_gui.views.scan_view import ScanView
from amrst_gui.views.scene import REGISTRATION_STAGES, build_registration_scene

_LABELS = {
    "before": "Before",
    "coarse": "After coarse",
    "fine": "After fine",
    "manual": "Manual",
}


class RegistrationPane(QWidget):
    """A stage selector above one ScanView showing both scans in the target frame.

    Listens to the session's result signals (``coarse_accepted``,
    ``fine_finished``, ``review_changed``, ...) and moves to the newest stage
    after ``coarse_accepted`` and ``fine_finished``; emits nothing.
    """

    def __init__(self, session, parent: QWidget | None = None) -> None:
        super().__init__(parent)
        self.setObjectName("registration_pane")
        self.session = session
        self.stage = "before"
        bar = QHBoxLayout()
        bar.setContentsMargins(4, 2, 4, 2)
        bar.addWidget(QLabel("Show:"))
        self.buttons = QButtonGroup(self)
        for i, stage in enumerate(REGISTRATION_STAGES):
            button = QRadioButton(_LABELS[stage])
            button.setToolTip(
                f"Overlay the target and the source {_LABELS[stage].lower()} "
                "registration (shortcut Alt+{})".format(i + 1)
            )
            button.setShortcut(f"Alt+{i + 1}")
            self.buttons.addButton(button, i)
            bar.addWidget(button)
        self.buttons.button(0).setChecked(True)
        self.buttons.idToggled.connect(self._on_stage_toggled)
        bar.addStretch(1)
        self.view = ScanView(self)
        layout = QVBoxLayout(self)
        layout.setContentsMargins(0, 0, 0, 0)
        layout.addLayout(bar)
        layout.addWidget(self.view, 1)
        for name in RESULT_SIGNALS:
            slot = getattr(self, f"_on_{name}", self._on_results_changed)
            getattr(session, name).connect(slot)
        session.manual_preview_changed.connect(self._on_manual_preview_changed)

    def set_stage(self, stage: str) -> None:
        """Show "before", "coarse" or "fine"."""
        self.buttons.button(REGISTRATION_STAGES.index(stage)).setChecked(True)

    def refresh(self) -> None:
        """Rebuild the overlay from the session and draw it."""
        self.view.update_scene(build_registration_scene(self.session, self.stage))

    def _on_stage_toggled(self, index: int, checked: bool) -> None:
        if checked:
            self.stage = REGISTRATION_STAGES[index]
            self.refresh()

    def _on_results_changed(self, *_args) -> None:
        self.refresh()

    def _on_manual_preview_changed(self, T) -> None:
        if self.stage == "manual":
            self.refresh()

    def _on_fine_finished(self, _fine) -> None:
        self._show(stage="fine")

    def _on_coarse_accepted(self, _coarse) -> None:
        self._show(stage="coarse")

    def _on_scan_loaded(self, _role) -> None:
        self._show(stage="before")

    def _on_scans_swapped(self) -> None:
        self._show(stage="before")

    def _show(self, stage: str) -> None:
        if stage != self.stage:
            self.set_stage(stage)  # refreshes through the toggled button
        else:
            self.refresh()
