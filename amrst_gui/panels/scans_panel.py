"""ScansPanel: which files are the target (reference) and the source, and swap."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
from PySide6.QtCore import Signal
from PySide6.QtWidgets import (
    QFormLayout,
    QGroupBox,
    QHBoxLayout,
    QLabel,
    QMenu,
    QPushButton,
    QToolButton,
    QVBoxLayout,
    QWidget,
)

from amrst_gui.drops import FileDropMixin

if TYPE_CHECKING:
    from amrst_gui.workers import StageJob

_TITLES = {
    "target": "Target (reference, stays fixed)",
    "source": "Source (moved onto target)",
}


class _RoleBox(FileDropMixin, QGroupBox):
    dropped = Signal(list)

    def __init__(self, role: str, parent: QWidget) -> None:
        super().__init__(_TITLES[role], parent)
        self.setObjectName(f"{role}_box")
        self.role = role
        self.setAcceptDrops(True)
        self.file = QLabel("-")
        self.file.setWordWrap(True)
        self.points = QLabel("-")
        self.attributes = QLabel("-")
        self.attributes.setWordWrap(True)
        self.offset = QLabel("-")
        self._described_cloud = None
        self._description = ""
        self._describing: StageJob | None = None
        form = QFormLayout()
        form.addRow("File:", self.file)
        form.addRow("Points:", self.points)
        form.addRow("Attributes:", self.attributes)
        form.addRow("Offset:", self.offset)
        self.open_button = QPushButton("Open…")
        self.open_button.setToolTip(
            f"Choose the {role} scan file (LAS, LAZ, PLY, PCD, XYZ…)"
        )
        self.recent_button = QToolButton()
        self.recent_button.setText("Recent")
        self.recent_button.setToolTip(f"Open a recently used file as the {role}")
        self.recent_button.setPopupMode(QToolButton.ToolButtonPopupMode.InstantPopup)
        self.recent_menu = QMenu(self.recent_button)
        self.recent_button.setMenu(self.recent_menu)
        buttons = QHBoxLayout()
        buttons.addWidget(self.open_button)
        buttons.addWidget(self.recent_button)
        buttons.addStretch(1)
        layout = QVBoxLayout(self)
        layout.addLayout(form)
        layout.addLayout(buttons)

    def show_cloud(self, cloud, path: Path | None) -> None:
        if cloud is not self._described_cloud:
            self._describe_later(cloud)
        if cloud is None:
            for label in (self.file, self.points, self.attributes, self.offset):
                label.setText("-")
            self.setToolTip("Drop a scan file here")
            return
        self.file.setText(path.name if path else cloud.name)
        self.file.setToolTip(str(path) if path else "")
        self.points.setText(f"{len(cloud):,}")
        attrs = sorted(cloud.attributes)
        self.attributes.setText(", ".join(attrs) if attrs else "none (xyz only)")
        off = np.asarray(cloud.offset)
        self.offset.setText(
            "none" if not off.any() else ", ".join(f"{v:.2f}" for v in off)
        )
        self.setToolTip(
            self._description
            or "Describing the scan (bounds, spacing)… Drop a scan file here to "
            "replace it"
        )

    def _describe_later(self, cloud) -> None:
        """Describe ``cloud`` in the engine process; the tooltip shows it once
        known."""
        from amrst_gui import engine_process, jobs, workers

        if self._describing is not None:
            self._describing.discard()
        self._described_cloud, self._description, self._describing = cloud, "", None
        if cloud is None:
            return

        def done(text: str, c=cloud) -> None:
            if c is self._described_cloud:
                self._description, self._describing = text, None
                self.setToolTip(text or "Drop a scan file here to replace it")

        self._describing = workers.run_stage(
            engine_process.in_engine(jobs.describe_scan, what="a scan's description"),
            cloud,
            name=f"describe {self.role}",
            on_result=done,
        )

    def close_jobs(self) -> None:
        """Drop a description still being computed (the window is closing)."""
        if self._describing is not None:
            self._describing.discard()
            self._describing = None

    def files_dropped_here(self, paths: list[Path]) -> None:
        self.dropped.emit(paths)


class ScansPanel(QWidget):
    """Target and source files: point counts, attributes, open, recent, swap.

    Listens to ``scan_loaded``, ``scans_swapped`` and ``busy_changed``; emits
    ``open_requested(role)``, ``recent_chosen(role, path)``,
    ``files_dropped(role, paths)`` and ``swap_requested()``.
    """

    open_requested = Signal(str)
    recent_chosen = Signal(str, str)
    files_dropped = Signal(str, list)
    swap_requested = Signal()

    def __init__(self, session, parent: QWidget | None = None) -> None:
        super().__init__(parent)
        self.setObjectName("scans_panel")
        self.session = session
        self.boxes = {role: _RoleBox(role, self) for role in ("target", "source")}
        self.swap_button = QPushButton("⇅ Swap target and source")
        self.swap_button.setToolTip(
            "Make the source the reference and the target the moved scan "
            "(clears the results; a loaded truth is inverted)"
        )
        self.swap_button.clicked.connect(self.swap_requested)
        layout = QVBoxLayout(self)
        layout.addWidget(self.boxes["target"])
        layout.addWidget(self.swap_button)
        layout.addWidget(self.boxes["source"])
        layout.addStretch(1)
        for role, box in self.boxes.items():
            box.open_button.clicked.connect(
                lambda _=False, r=role: self.open_requested.emit(r)
            )
            box.dropped.connect(lambda paths, r=role: self.files_dropped.emit(r, paths))
        session.scan_loaded.connect(self._on_scan_loaded)
        session.scans_swapped.connect(self._on_scans_swapped)
        session.busy_changed.connect(self._on_busy_changed)
        self.refresh()

    def close_jobs(self) -> None:
        """Drop the descriptions still being computed (the window is closing)."""
        for box in self.boxes.values():
            box.close_jobs()

    def set_recent_files(self, paths: list[str]) -> None:
        """Fill both Recent menus."""
        for role, box in self.boxes.items():
            box.recent_menu.clear()
            for path in paths:
                action = box.recent_menu.addAction(Path(path).name)
                action.setToolTip(path)
                action.triggered.connect(
                    lambda _=False, r=role, p=path: self.recent_chosen.emit(r, p)
                )
            box.recent_button.setEnabled(bool(paths))

    def refresh(self) -> None:
        """Show what the session holds."""
        for role, box in self.boxes.items():
            box.show_cloud(self.session.cloud(role), self.session.path(role))
        self.swap_button.setEnabled(self.session.has_scans and not self.session.busy)

    def _on_scan_loaded(self, _role: str) -> None:
        self.refresh()

    def _on_scans_swapped(self) -> None:
        self.refresh()

    def _on_busy_changed(self, busy: bool) -> None:
        self.swap_button.setEnabled(self.session.has_scans and not busy)
        for box in self.boxes.values():
            box.open_button.setEnabled(not busy)
            box.recent_button.setEnabled(not busy and not box.recent_menu.isEmpty())
