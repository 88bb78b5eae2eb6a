"""ParamsPanel: every stage's parameters, built from the dataclass fields.

The form edits a draft; Apply makes a new frozen RegistrationParams with
``dataclasses.replace`` and emits it (as magicgui does).
"""

from __future__ import annotations

import dataclasses
from typing import Any

from PySide6.QtCore import Qt, Signal
from PySide6.QtWidgets import (
    QComboBox,
    QFormLayout,
    QGroupBox,
    QHBoxLayout,
    QLabel,
    QPushButton,
    QScrollArea,
    QVBoxLayout,
    QWidget,
)

from amrst_gui.panels.param_editors import (
    editor_value,
    field_label,
    make_editor,
    set_editor_value,
)
from amrst_gui.panels.verdict_style import ERROR_STYLE
from amrst_gui.panels.wheel_guard import WheelGuard

_GROUP_TITLES = {
    "preprocess": "Preprocess (outliers, thinning)",
    "separate": "Wood / leaf separation",
    "skeleton": "Skeleton",
    "keypoints": "Key points",
    "match": "Tetrahedron matching",
    "coarse": "Candidate verification (coarse)",
    "fine": "Fine registration (ICP)",
    "trunk": "Trunk heading search",
    "metrics": "Metrics",
    "measure": "Tree measurements (height, DBH, crown)",
}


class ParamsPanel(QWidget):
    """One group per stage; presets, reset to defaults, Apply.

    Listens to ``params_changed`` (shows the session's params) and
    ``busy_changed``; emits ``params_applied(RegistrationParams)``.
    """

    params_applied = Signal(object)

    def __init__(self, session, parent: QWidget | None = None) -> None:
        super().__init__(parent)
        self.setObjectName("params_panel")
        self.session = session
        self.editors: dict[tuple[str, str], QWidget] = {}
        self._dirty = False
        self.preset = QComboBox()
        self.preset.setToolTip("Load a preset into the form (then Apply)")
        self.preset.addItem("Preset…", None)
        for name in self._presets():
            self.preset.addItem(name, name)
        self.preset.activated.connect(self._on_preset_activated)
        reset = QPushButton("Defaults")
        reset.setToolTip("Put the default values in the form (then Apply)")
        reset.clicked.connect(self._on_reset_clicked)
        self.apply_button = QPushButton("Apply")
        self.apply_button.setToolTip(
            "Use these values; steps that depend on them become stale"
        )
        self.apply_button.clicked.connect(self.apply)
        self.state = QLabel("")
        self.state.setWordWrap(True)
        top = QHBoxLayout()
        top.addWidget(self.preset, 1)
        top.addWidget(reset)
        top.addWidget(self.apply_button)

        body = QWidget()
        body_layout = QVBoxLayout(body)
        params = session.params
        for group in dataclasses.fields(params):
            values = getattr(params, group.name)
            box = QGroupBox(_GROUP_TITLES.get(group.name, group.name))
            box.setObjectName(f"group_{group.name}")
            form = QFormLayout(box)
            for f in dataclasses.fields(values):
                editor = make_editor(f, getattr(values, f.name))
                self._connect_dirty(editor)
                label = QLabel(field_label(f.name))
                label.setWordWrap(True)  # a long name wraps; the value keeps its room
                label.setToolTip(editor.toolTip())
                form.addRow(label, editor)
                self.editors[(group.name, f.name)] = editor
            body_layout.addWidget(box)
        body_layout.addStretch(1)
        scroll = QScrollArea()
        scroll.setWidgetResizable(True)
        scroll.setHorizontalScrollBarPolicy(Qt.ScrollBarPolicy.ScrollBarAlwaysOff)
        scroll.setWidget(body)
        self._wheel = WheelGuard(scroll)
        self._wheel.guard(body)
        layout = QVBoxLayout(self)
        layout.setContentsMargins(2, 2, 2, 2)
        layout.addLayout(top)
        layout.addWidget(self.state)
        layout.addWidget(scroll, 1)
        session.params_changed.connect(self._on_params_changed)
        # A running chain of steps uses one set of parameters: Apply waits for it.
        session.busy_changed.connect(self._update_apply)
        self.show_params(params)

    def draft(self) -> Any:
        """RegistrationParams built from the form (raises ValueError if invalid)."""
        params = self.session.params
        groups = {}
        for group in dataclasses.fields(params):
            values = getattr(params, group.name)
            changes = {
                f.name: editor_value(
                    self.editors[(group.name, f.name)], getattr(values, f.name)
                )
                for f in dataclasses.fields(values)
            }
            groups[group.name] = dataclasses.replace(values, **changes)
        return dataclasses.replace(params, **groups)

    def show_params(self, params: Any) -> None:
        """Fill the form with ``params``."""
        for (group, name), editor in self.editors.items():
            editor.blockSignals(True)
            set_editor_value(editor, getattr(getattr(params, group), name))
            editor.blockSignals(False)
        self._set_dirty(False)

    def apply(self) -> None:
        """Emit the form's values as new params (or show why they are invalid)."""
        try:
            params = self.draft()
        except (ValueError, TypeError) as exc:
            self.state.setText(f"Not applied: {exc}")
            self.state.setStyleSheet(ERROR_STYLE)
            return
        self.params_applied.emit(params)
        self._set_dirty(False)

    def _presets(self) -> list[str]:
        try:
            from amrst import params as params_io

            return sorted(params_io.list_presets())
        except ImportError:
            return []

    def load_preset(self, name: str) -> None:
        """Put a preset's values in the form (Apply uses them)."""
        from amrst import params as params_io
        from amrst.errors import AmrstError

        try:
            params = params_io.load_preset(name)
        except AmrstError as exc:
            self.state.setText(f"Preset '{name}' not loaded: {exc}")
            self.state.setStyleSheet(ERROR_STYLE)
            return
        self.show_params(params)
        self._set_dirty(True, f"Preset '{name}' loaded into the form: press Apply.")

    def _on_preset_activated(self, index: int) -> None:
        name = self.preset.itemData(index)
        self.preset.setCurrentIndex(0)
        if name is not None:
            self.load_preset(name)

    def _on_reset_clicked(self) -> None:
        self.show_params(type(self.session.params)())
        self._set_dirty(True, "Defaults loaded into the form: press Apply.")

    def _on_params_changed(self, params: Any) -> None:
        self.show_params(params)

    def _connect_dirty(self, editor: QWidget) -> None:
        for signal in ("valueChanged", "toggled", "currentIndexChanged", "textEdited"):
            if hasattr(editor, signal):
                getattr(editor, signal).connect(lambda *_: self._set_dirty(True))
                return

    def _update_apply(self, *_args) -> None:
        self.apply_button.setEnabled(self._dirty and not self.session.busy)

    def _set_dirty(self, dirty: bool, text: str = "") -> None:
        self._dirty = dirty
        self._update_apply()
        self.state.setStyleSheet("color: #b06000;" if dirty else "")
        self.state.setText(
            text or ("Changed: press Apply to use these values." if dirty else "")
        )
