"""ExportDialog, AboutDialog, the shortcuts list and the discard question.

The dialogs do not block (open()); only :func:`confirm_discard` waits for its answer,
because the action it guards goes on or not on that answer.
"""

from __future__ import annotations

import os
import platform
from importlib import metadata
from pathlib import Path

from PySide6 import __version__ as pyside_version
from PySide6.QtCore import qVersion
from PySide6.QtGui import QKeySequence
from PySide6.QtWidgets import (
    QCheckBox,
    QComboBox,
    QDialog,
    QDialogButtonBox,
    QFileDialog,
    QFormLayout,
    QGroupBox,
    QHBoxLayout,
    QLabel,
    QLineEdit,
    QMessageBox,
    QPushButton,
    QVBoxLayout,
)

from amrst_gui.panels.verdict_style import ERROR_STYLE

EXPORT_PARTS = (
    ("registered", "Registered source cloud", "The source moved into the target frame"),
    (
        "merged",
        "Merged cloud (with a scan_id field)",
        "Target and moved source in one file; scan_id 0 = target, 1 = source",
    ),
    ("transform", "Transform (JSON + 4×4 text)", "T_target_source, coarse and final"),
    (
        "metrics",
        "Metrics (CSV + JSON)",
        "RMSE, Hausdorff, overlap, truth errors, timings",
    ),
    ("params", "Parameters (params.json)", "Everything needed to run it again"),
)
CLOUD_FORMATS = ("ply", "las", "laz", "pcd")
# The folder proposed for a case's first export, inside the case's folder.
EXPORT_SUBFOLDER = "registration"


def export_folder(remembered: str, base: Path | None) -> str:
    """The folder the export dialog starts from: the one used last when it lies in
    the current case's folder (:func:`case_folder` of ``base``, the target scan's),
    else one inside it (the previous case's folder is never proposed for another
    case)."""
    if base is None:
        return remembered
    case = case_folder(base)
    if remembered:
        path = Path(remembered).expanduser()
        if path.is_absolute() and path.resolve().is_relative_to(case.resolve()):
            return remembered
    return str(case / EXPORT_SUBFOLDER)


def case_folder(base: Path) -> Path:
    """Where a case's exports go: ``base``, or ``~/AMRST/<its name>-<tag>`` where
    ``base`` holds the app's own files (the bundled sample) or cannot be written;
    the tag, from ``base``'s full path, keeps two such folders of one name apart."""
    import hashlib

    from amrst.resources import resources_root

    where = base.resolve()
    if where.is_relative_to(resources_root().resolve()) or not os.access(base, os.W_OK):
        tag = hashlib.sha1(str(where).encode()).hexdigest()[:6]
        return Path.home() / "AMRST" / f"{base.name}-{tag}"
    return base


def confirm_replace(parent, folder: Path, before: str) -> bool:
    """Ask whether what another run wrote in ``folder`` (``before`` says what) is
    replaced."""
    box = QMessageBox(
        QMessageBox.Icon.Warning,
        "Replace another run's files?",
        f"{folder} holds {before}, not the export of the scans open now.",
        QMessageBox.StandardButton.Cancel,
        parent,
    )
    box.setObjectName("replace_box")
    box.setInformativeText(
        "Cancel, then choose another folder, to keep it; Replace writes this pair's "
        "files over it."
    )
    replace = box.addButton("Replace", QMessageBox.ButtonRole.DestructiveRole)
    box.setDefaultButton(QMessageBox.StandardButton.Cancel)
    box.exec()
    return box.clickedButton() is replace


def confirm_discard(parent, action: str, lost: str, keep: str = "") -> bool:
    """Ask whether ``action`` may throw away ``lost`` (an unexported result, pairs);
    ``keep`` says how to keep it."""
    box = QMessageBox(
        QMessageBox.Icon.Warning,
        "Discard unsaved work?",
        f"{action} discards {lost}.",
        QMessageBox.StandardButton.Discard | QMessageBox.StandardButton.Cancel,
        parent,
    )
    box.setObjectName("discard_box")
    box.setInformativeText(f"Choose Cancel to keep it: {keep}." if keep else "")
    box.setDefaultButton(QMessageBox.StandardButton.Cancel)
    return box.exec() == QMessageBox.StandardButton.Discard


def open_report(_parent, path: Path) -> bool:
    """Show a report.html in the default web browser; False when none opens it."""
    from PySide6.QtCore import QUrl
    from PySide6.QtGui import QDesktopServices

    return bool(QDesktopServices.openUrl(QUrl.fromLocalFile(str(path))))


def confirm_override(parent, verdict) -> bool:
    """Ask whether a result whose verdict is not *registered* is exported anyway."""
    box = QMessageBox(
        QMessageBox.Icon.Warning,
        "Export a result that is not registered?",
        f"The verdict is '{verdict.status}': {verdict.reason}",
        QMessageBox.StandardButton.Cancel,
        parent,
    )
    box.setObjectName("override_box")
    box.setInformativeText(
        f"Next: {verdict.next_step}\n\nExport anyway writes the files with this "
        "verdict and your override recorded in transform.json and metrics.json."
    )
    anyway = box.addButton("Export anyway", QMessageBox.ButtonRole.AcceptRole)
    box.setDefaultButton(QMessageBox.StandardButton.Cancel)
    box.exec()
    return box.clickedButton() is anyway


class ExportDialog(QDialog):
    """Where to write, what, and in which point-cloud format.

    Emits QDialog's ``accepted``; read ``folder()``, ``cloud_format()`` and ``parts()``.
    A relative folder is taken relative to the case's folder (:func:`case_folder` of
    ``base``, the target scan's folder), not to wherever the app was started from;
    the folder proposed lies in it (:func:`export_folder`). A folder holding another
    pair's export is accepted only once the user agrees to replace it
    (``session.allow_replacing``); ``session`` defaults to the parent window's.
    """

    def __init__(
        self,
        parent=None,
        folder: str = "",
        cloud_format: str = "ply",
        base: Path | None = None,
        session=None,
    ) -> None:
        super().__init__(parent)
        # Found once: folder() runs at every keystroke, and this looks at the disk.
        self.case = Path.cwd() if base is None else case_folder(base)
        self.session = (
            session if session is not None else getattr(parent, "session", None)
        )
        folder = export_folder(folder, base)
        self.setObjectName("export_dialog")
        self.setWindowTitle("Export registration")
        self.folder_edit = QLineEdit(folder)
        # Wide enough to read a folder's path, not only its last part.
        self.folder_edit.setMinimumWidth(self.fontMetrics().averageCharWidth() * 60)
        self.folder_edit.setPlaceholderText("Output folder")
        self.folder_edit.setToolTip(
            "Files are written here; the same pair's earlier export is replaced, "
            "another pair's only if you agree"
        )
        browse = QPushButton("Browse…")
        browse.clicked.connect(self._browse)
        row = QHBoxLayout()
        row.addWidget(self.folder_edit, 1)
        row.addWidget(browse)
        self.part_boxes: dict[str, QCheckBox] = {}
        parts_box = QGroupBox("Write")
        parts_layout = QVBoxLayout(parts_box)
        for key, label, tip in EXPORT_PARTS:
            box = QCheckBox(label)
            box.setChecked(True)
            box.setToolTip(tip)
            box.toggled.connect(self._validate)
            parts_layout.addWidget(box)
            self.part_boxes[key] = box
        self.format_combo = QComboBox()
        for fmt in CLOUD_FORMATS:
            self.format_combo.addItem(fmt.upper(), fmt)
        self.format_combo.setCurrentIndex(
            max(
                0,
                CLOUD_FORMATS.index(cloud_format)
                if cloud_format in CLOUD_FORMATS
                else 0,
            )
        )
        self.format_combo.setToolTip(
            "LAS/LAZ keep georeferencing offsets and LAS fields; "
            "PLY and PCD are read by most tools"
        )
        form = QFormLayout()
        form.addRow("Folder:", row)
        form.addRow("Cloud format:", self.format_combo)
        self.problem = QLabel("")
        self.problem.setStyleSheet(ERROR_STYLE)
        self.buttons = QDialogButtonBox(
            QDialogButtonBox.StandardButton.Ok | QDialogButtonBox.StandardButton.Cancel
        )
        self.buttons.button(QDialogButtonBox.StandardButton.Ok).setText("Export")
        self.buttons.accepted.connect(self.accept)
        self.buttons.rejected.connect(self.reject)
        layout = QVBoxLayout(self)
        layout.addLayout(form)
        layout.addWidget(parts_box)
        layout.addWidget(self.problem)
        layout.addWidget(self.buttons)
        self.folder_edit.textChanged.connect(self._validate)
        self._validate()

    def folder(self) -> Path:
        """The chosen output folder (absolute)."""
        path = Path(self.folder_edit.text().strip()).expanduser()
        if not path.is_absolute():
            path = self.case / path
        return path

    def accept(self) -> None:
        """Close with Export, unless the folder holds another pair's export and the
        user keeps it."""
        if self._may_write():
            super().accept()

    def _may_write(self) -> bool:
        from amrst.errors import InvalidInput
        from amrst.results.export import check_output_dir, output_names

        s = self.session
        folder = self.folder()
        try:  # a name too long, a file in the way...: said here, the dialog open
            check_output_dir(folder, output_names(self.parts(), self.cloud_format()))
        except InvalidInput as exc:
            self.problem.setText(str(exc))
            return False
        if s is None:
            return True
        before = s.other_export(folder)
        if before is None:
            return True
        if confirm_replace(self, folder, before):
            s.allow_replacing(folder)
            return True
        self.problem.setText(
            "That folder holds another run's files: choose another folder."
        )
        return False

    def cloud_format(self) -> str:
        """ "ply", "las", "laz" or "pcd"."""
        return str(self.format_combo.currentData())

    def parts(self) -> tuple[str, ...]:
        """The parts to write, in export_registration's names."""
        return tuple(k for k, box in self.part_boxes.items() if box.isChecked())

    def _validate(self, *_args) -> None:
        problem = ""
        if not self.folder_edit.text().strip():
            problem = "Choose an output folder."
        elif not self.parts():
            problem = "Choose at least one thing to write."
        self.problem.setText(problem)
        self.buttons.button(QDialogButtonBox.StandardButton.Ok).setEnabled(not problem)

    def _browse(self) -> None:
        folder = QFileDialog.getExistingDirectory(
            self, "Export to folder", self.folder_edit.text()
        )
        if folder:
            self.folder_edit.setText(folder)


def library_versions() -> dict[str, str]:
    """Versions of AMRST and the libraries it runs on."""
    import amrst

    def dist(*names: str) -> str:
        for name in names:
            try:
                return metadata.version(name)
            except metadata.PackageNotFoundError:
                continue
        return "not installed"

    try:
        from vtkmodules.vtkCommonCore import vtkVersion

        vtk = vtkVersion.GetVTKVersion()
    except ImportError:
        vtk = "not installed"
    return {
        "AMRST": amrst.__version__,
        "AMRST Studio": dist("amrst-studio"),
        "Qt": qVersion(),
        "PySide6": pyside_version,
        "VTK": vtk,
        "pyvista": dist("pyvista"),
        "pyvistaqt": dist("pyvistaqt"),
        "superqt": dist("superqt"),
        "open3d": dist("open3d-cpu", "open3d"),
        "numpy": dist("numpy"),
        "scipy": dist("scipy"),
        "Python": platform.python_version(),
    }


class AboutDialog(QDialog):
    """What AMRST Studio is, and the versions it runs on."""

    def __init__(self, parent=None) -> None:
        super().__init__(parent)
        self.setObjectName("about_dialog")
        self.setWindowTitle("About AMRST Studio")
        self.versions = library_versions()
        rows = "".join(
            f"<tr><td>{k}</td><td>&nbsp;{v}</td></tr>" for k, v in self.versions.items()
        )
        text = QLabel(
            "<h3>AMRST Studio</h3>"
            "<p>Marker-free registration of two terrestrial laser scans of one tree: "
            "wood/leaf separation, skeletons, similar tetrahedra between key points "
            "(AMRST), review by eye, ICP refinement, export.</p>"
            f"<table>{rows}</table>"
        )
        text.setWordWrap(True)
        buttons = QDialogButtonBox(QDialogButtonBox.StandardButton.Close)
        buttons.rejected.connect(self.reject)
        layout = QVBoxLayout(self)
        layout.addWidget(text)
        layout.addWidget(buttons)


class ShortcutsDialog(QDialog):
    """Every action with a shortcut, in menu order."""

    def __init__(self, actions, parent=None) -> None:
        super().__init__(parent)
        self.setObjectName("shortcuts_dialog")
        self.setWindowTitle("Keyboard shortcuts")
        rows = []
        for action in actions:
            key = action.shortcut().toString(QKeySequence.SequenceFormat.NativeText)
            if key:
                label = (
                    action.text()
                    .replace("&&", "\0")
                    .replace("&", "")
                    .replace("\0", "&")
                )
                rows.append(f"<tr><td><b>{key}</b></td><td>&nbsp;{label}</td></tr>")
        rows.append(
            "<tr><td><b>Alt+1/2/3</b></td><td>&nbsp;Registration view: "
            "before / coarse / fine</td></tr>"
        )
        text = QLabel(
            f"<table>{''.join(rows)}</table><p>Delete and R act on the "
            "selected match while the Matches dock has focus.</p>"
        )
        buttons = QDialogButtonBox(QDialogButtonBox.StandardButton.Close)
        buttons.rejected.connect(self.reject)
        layout = QVBoxLayout(self)
        layout.addWidget(text)
        layout.addWidget(buttons)


def load_params(window) -> None:
    """Ask for a parameter file and give it to the window's session."""
    from PySide6.QtWidgets import QFileDialog

    from amrst import params as params_io
    from amrst.errors import AmrstError
    from amrst_gui import steps

    path, _ = QFileDialog.getOpenFileName(
        window, "Load parameters", "", "JSON (*.json)"
    )
    if path:
        try:
            loaded = params_io.load_params(path)
        except AmrstError as exc:
            window.session.report_error(f"Could not load parameters: {exc}")
            return
        window.session.set_params(loaded)
        if steps.values_equal(window.session.params, loaded):  # not refused (busy)
            window.status.show_message(
                f"Parameters loaded from {path}; steps they change read (stale)."
            )


def save_params(window) -> None:
    """Ask where to write the session's parameters as JSON, and write them."""
    from PySide6.QtWidgets import QFileDialog

    from amrst import params as params_io
    from amrst.errors import AmrstError

    path, _ = QFileDialog.getSaveFileName(
        window, "Save parameters", "params.json", "JSON (*.json)"
    )
    if path:
        try:
            params_io.save_params(path, window.session.params)
        except (OSError, AmrstError) as exc:
            window.session.report_error(f"Could not save the parameters: {exc}")
            return
        window.status.show_message(f"Parameters saved to {path}")
