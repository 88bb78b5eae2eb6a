"""ManualPanel: recover the pose by hand when matching fails.

Point pairs picked in the two scan views (each click snaps to the nearest point;
each picked point marked and numbered in its view; the pairs loaded from or saved to
a CSV file), a nudge (turn about the vertical, shift) with a live score, or a typed
or loaded 4x4 transform. Each makes a candidate of origin "manual" through
``session.add_manual_pose``; Accept coarse and Fine then start from it.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from PySide6.QtWidgets import (
    QAbstractItemView,
    QCheckBox,
    QFileDialog,
    QGroupBox,
    QHBoxLayout,
    QHeaderView,
    QLabel,
    QPlainTextEdit,
    QPushButton,
    QScrollArea,
    QTableWidget,
    QTableWidgetItem,
    QVBoxLayout,
    QWidget,
)

from amrst.errors import InvalidInput
from amrst.review import manual
from amrst.types import local_transform, rotation_angle_deg
from amrst_gui.panels import pair_fit
from amrst_gui.panels.manual_nudge import NudgeMixin
from amrst_gui.panels.wheel_guard import WheelGuard

_PAIR_COLUMNS = ("#", "Target point (m)", "dX", "dY", "dZ", "Dist.")
# Points of each scan drawn as the other's ghost while picking under a rough pose.
_GHOST_POINTS = 60_000


def _xyz(p) -> str:
    return f"{p[0]:.2f}, {p[1]:.2f}, {p[2]:.2f}"


class ManualPanel(NudgeMixin, QScrollArea):
    """Point pairs, nudge and typed transform.

    Listens to the views' ``point_picked`` and the session's ``scan_loaded``,
    ``scans_swapped``, ``matches_changed`` and ``selection_changed``; calls
    ``session.add_manual_pose`` and ``session.set_manual_preview``.
    """

    def __init__(self, session, target_view, source_view, parent=None) -> None:
        super().__init__(parent)
        self.setObjectName("manual_panel")
        self.setWidgetResizable(True)
        self.session = session
        self.views = {"target": target_view, "source": source_view}
        self.pairs: list[tuple[np.ndarray, np.ndarray]] = []
        self._saved: list[tuple[np.ndarray, np.ndarray]] = []  # as last saved or read
        self._undo: list[list] = []
        self._pending: np.ndarray | None = None  # a target point waiting for its pair
        self.fit: manual.PairFit | None = None
        self._score_cache: tuple | None = None
        self._stem_cache: tuple | None = None  # (source cloud, its stem's centre)
        self._score_stale = False  # the nudge's score waits until it is shown
        body = QWidget()
        layout = QVBoxLayout(body)
        layout.setContentsMargins(4, 4, 4, 4)
        layout.addWidget(self._pairs_box())
        layout.addWidget(self._nudge_box())
        layout.addWidget(self._typed_box())
        layout.addStretch(1)
        self.setWidget(body)
        self._wheel = WheelGuard(self)
        self._wheel.guard(body)
        for view in self.views.values():
            view.point_picked.connect(self._on_point_picked)
        for name in ("scan_loaded", "scans_swapped"):
            getattr(session, name).connect(self._on_scans_changed)
        for name in ("matches_changed", "selection_changed", "coarse_accepted"):
            getattr(session, name).connect(self._on_base_changed)
        session.unsaved_work.append(
            (self.unsaved_pairs, "Save pairs… in the Manual pose dock keeps them")
        )
        self._show_pairs()

    def unsaved_pairs(self) -> str:
        """Say how many point pairs were picked and not saved ("" for none)."""
        same = len(self.pairs) == len(self._saved) and all(
            a is b for a, b in zip(self.pairs, self._saved, strict=True)
        )
        return (
            ""
            if not self.pairs or same
            else f"{len(self.pairs)} point pair{'s' if len(self.pairs) != 1 else ''} "
            "(not saved)"
        )

    # ------------------------------------------------------------- building

    def showEvent(self, event) -> None:
        super().showEvent(event)
        if self._score_stale:
            self._on_nudged()

    def _pairs_box(self) -> QGroupBox:
        box = QGroupBox("Point pairs")
        grid = QVBoxLayout(box)
        self.pick_button = QPushButton("Pick point pairs")
        self.pick_button.setCheckable(True)
        self.pick_button.setToolTip(
            "Click a point in the target view, then the same point in the source "
            "view (Scans tab); each click snaps to the nearest scan point. Drag to "
            "turn the view as usual."
        )
        self.pick_button.toggled.connect(self.set_picking)
        self.levelled = QCheckBox("Levelled: turn about the vertical + shift only")
        self.levelled.setChecked(True)
        self.levelled.setToolTip(
            "For scans levelled in the field: 2 pairs are enough and the fit cannot "
            "tilt the tree. Off: a full rotation from 3 or more pairs."
        )
        self.levelled.toggled.connect(lambda _on: self._show_pairs())
        self.hint = QLabel("")
        self.hint.setWordWrap(True)
        lock_row = self._pick_options()
        self.table = QTableWidget(0, len(_PAIR_COLUMNS))
        self.table.setObjectName("pairs_table")
        self.table.setHorizontalHeaderLabels(list(_PAIR_COLUMNS))
        for col in range(2, len(_PAIR_COLUMNS)):
            header_item = self.table.horizontalHeaderItem(col)
            assert header_item is not None
            header_item.setToolTip(
                "Source point moved by the fit minus its target point (cm), along "
                "x, y, z of the target and as a distance. Good: about the point "
                "spacing (1-3 cm); a pair far above the others was mis-picked: "
                "delete it."
            )
        self.table.verticalHeader().hide()
        self.table.setSelectionBehavior(QAbstractItemView.SelectionBehavior.SelectRows)
        self.table.setEditTriggers(QTableWidget.EditTrigger.NoEditTriggers)
        self.table.horizontalHeader().setSectionResizeMode(
            QHeaderView.ResizeMode.ResizeToContents
        )
        # About six pairs in view: more scroll in the table, so the locks and the
        # Nudge below stay within reach on a laptop screen.
        self.table.setMinimumHeight(110)
        self.table.setMaximumHeight(180)
        buttons = QHBoxLayout()
        self.delete_button = QPushButton("Delete pair")
        self.delete_button.clicked.connect(self.delete_selected)
        self.undo_button = QPushButton("Undo")
        self.undo_button.clicked.connect(self.undo)
        self.use_pairs = QPushButton("Use as candidate")
        self.use_pairs.setToolTip(
            "Add the pose the point pairs fit to the Matches list (origin manual), "
            "verified like the others; then Accept coarse and Fine start from it. "
            "The Nudge's turn and shift are not in it: 'Use nudged pose' adds those."
        )
        self.use_pairs.clicked.connect(self.use_pair_fit)
        for b in (self.delete_button, self.undo_button, self.use_pairs):
            buttons.addWidget(b)
        self.fit_label = QLabel("")
        self.fit_label.setObjectName("pairs_fit")
        self.fit_label.setWordWrap(True)
        # Room for a fit's usual three lines: the controls below do not jump
        # under the cursor when a pair is added or undone.
        self.fit_label.setMinimumHeight(3 * self.fit_label.fontMetrics().lineSpacing())
        # The buttons and the fit first: in sight on a laptop screen, with the
        # table and the options below them.
        grid.addWidget(self.pick_button)
        grid.addLayout(buttons)
        for widget in (self.fit_label, self.hint, self.table):
            grid.addWidget(widget)
        grid.addWidget(self.levelled)
        grid.addLayout(lock_row)
        grid.addWidget(self.ghost)
        grid.addLayout(self._files_row())
        return box

    def _pick_options(self) -> QHBoxLayout:
        """The shift locks (their row) and the ghost check box."""
        self.locks = [QCheckBox(f"no {axis} shift") for axis in "xyz"]
        row = QHBoxLayout()
        for lock, axis in zip(self.locks, "xyz", strict=True):
            lock.setToolTip(
                f"Hold the world shift along {axis} at zero (levelled fit only): "
                "scanners set up on the same line or at the same height."
            )
            lock.toggled.connect(lambda _on: self._show_pairs())
            row.addWidget(lock)
        self.levelled.toggled.connect(self._enable_locks)
        self.ghost = QCheckBox("Show the other scan under the rough pose")
        self.ghost.setToolTip(
            "Once a rough pose exists, draw the other scan faintly in each view, moved "
            "by it: the same side of the trunk is then easy to find. The pose is the "
            "fit of the pairs while there are any, else the selected match, turned "
            "and moved by the nudge. Clicks still pick the view's own scan."
        )
        self.ghost.toggled.connect(lambda _on: self._show_ghosts())
        self.session.manual_preview_changed.connect(lambda _T: self._show_ghosts())
        return row

    def _files_row(self) -> QHBoxLayout:
        files = QHBoxLayout()
        load = QPushButton("Load pairs…")
        load.setToolTip(
            "Read pairs from a CSV file: target_x,target_y,target_z,source_x,"
            "source_y,source_z in world coordinates (as amrst register --pairs)"
        )
        load.clicked.connect(self._load_pairs_dialog)
        self.save_button = QPushButton("Save pairs…")
        self.save_button.setToolTip("Write the pairs to a CSV file (world coordinates)")
        self.save_button.clicked.connect(self._save_pairs_dialog)
        files.addWidget(load)
        files.addWidget(self.save_button)
        return files

    def _typed_box(self) -> QGroupBox:
        box = QGroupBox("Type or load a transform")
        lay = QVBoxLayout(box)
        self.text = QPlainTextEdit()
        self.text.setPlaceholderText(
            "4 rows of 4 numbers (world T_target_source, as transform.txt), or the "
            "JSON of transform.json"
        )
        self.text.setMaximumHeight(90)
        row = QHBoxLayout()
        load = QPushButton("Load file…")
        load.clicked.connect(self._load_dialog)
        self.use_typed = QPushButton("Use typed transform")
        self.use_typed.clicked.connect(self.use_typed_transform)
        row.addWidget(load)
        row.addWidget(self.use_typed)
        lay.addWidget(self.text)
        lay.addLayout(row)
        return box

    # --------------------------------------------------------------- pairs
    def set_picking(self, on: bool) -> None:
        """Let clicks in the scan views pick pairs."""
        if self.pick_button.isChecked() != on:
            self.pick_button.setChecked(on)
            return
        s = self.session
        for role, view in self.views.items():
            cloud = s.cloud(role)
            view.set_picking(on, None if cloud is None else cloud.xyz)
        self._pending = None
        self._show_pairs()

    def _on_point_picked(self, _index: int, xyz) -> None:
        view = self.sender()
        role = next((r for r, v in self.views.items() if v is view), None)
        if role == "target":
            self._pending = np.asarray(xyz, float)
        elif role == "source" and self._pending is not None:
            self._undo.append(list(self.pairs))
            self.pairs.append((self._pending, np.asarray(xyz, float)))
            self._pending = None
        self._show_pairs()

    def add_pair(self, target_xyz, source_xyz) -> None:
        """Add one pair (local coordinates of each scan)."""
        self._undo.append(list(self.pairs))
        self.pairs.append(
            (np.asarray(target_xyz, float), np.asarray(source_xyz, float))
        )
        self._show_pairs()

    def delete_selected(self) -> None:
        rows = sorted({i.row() for i in self.table.selectedIndexes()}, reverse=True)
        if not rows and self.pairs:
            rows = [len(self.pairs) - 1]
        if rows:
            self._undo.append(list(self.pairs))
            for r in rows:
                del self.pairs[r]
            self._show_pairs()

    def undo(self) -> None:
        if self._undo:
            self.pairs = self._undo.pop()
            self._show_pairs()

    def _enable_locks(self, levelled: bool) -> None:
        for lock in self.locks:
            lock.setEnabled(levelled)

    def _fit_pairs(self) -> None:
        """Fit the pairs when there are enough (the label says why not)."""
        self.fit = None
        need = 2 if self.levelled.isChecked() else 3
        s = self.session
        if len(self.pairs) < need or not s.has_scans:
            self.fit_label.setText(f"{len(self.pairs)} of {need} pairs needed.")
            return
        locks = tuple(b.isChecked() for b in self.locks)
        try:
            self.fit = pair_fit.fit_pairs(
                s.cloud("target"),
                s.cloud("source"),
                self.pairs,
                self.levelled.isChecked(),
                (locks[0], locks[1], locks[2]),
            )
        except InvalidInput as exc:
            self.fit_label.setText(str(exc))
            return
        T = self.fit.T_target_source
        weak = manual.weak_turn(np.array([tp for tp, _sp in self.pairs]))
        text = (
            f"Achievable RMS of {len(self.pairs)} pairs: "
            f"{self.fit.rmse_m * 100:.1f} cm; turn "
            f"{rotation_angle_deg(T[:3, :3]):.1f}°, shift "
            f"{np.linalg.norm(T[:3, 3]):.2f} m. The overlay's Manual view shows it."
        )
        self.fit_label.setText(f"{text} {weak}" if weak else text)

    def _fill_table(self) -> None:
        """One row per pair (dX, dY, dZ and distance under the fit, cm), and one for
        a target point waiting for its source point."""
        d = (
            pair_fit.residual_vectors(self.fit.T_target_source, self.pairs) * 100
            if self.fit is not None
            else None
        )
        pending = self._pending is not None
        self.table.setRowCount(len(self.pairs) + pending)
        for i, (tp, sp) in enumerate(self.pairs):
            cells = [str(i + 1), _xyz(tp)]
            if d is not None:
                cells += [f"{v:+.1f}" for v in d[i]]
                cells.append(f"{np.linalg.norm(d[i]):.1f} cm")
            for j, text in enumerate(cells):
                item = QTableWidgetItem(text)
                item.setToolTip(f"target {_xyz(tp)} m, source {_xyz(sp)} m (local)")
                self.table.setItem(i, j, item)
            for j in range(len(cells), len(_PAIR_COLUMNS)):
                self.table.setItem(i, j, QTableWidgetItem(""))
        if self._pending is not None:
            row = len(self.pairs)
            cells = [str(row + 1), _xyz(self._pending), "", "", "", "source?"]
            for j, text in enumerate(cells):
                self.table.setItem(row, j, QTableWidgetItem(text))

    def _show_marks(self) -> None:
        """Number every picked point in its view; the waiting one in its colour."""
        labels = [str(i + 1) for i in range(len(self.pairs))]
        for k, (role, view) in enumerate(self.views.items()):
            xyz = np.array([p[k] for p in self.pairs], float).reshape(-1, 3)
            pending = self._pending if role == "target" else None
            view.marks.set_markers(xyz, labels, pending)

    def _show_ghosts(self) -> None:
        """The other scan faintly in each view under the rough pose, if wanted."""
        s = self.session
        T = s.manual_preview
        # Say which pose moves the ghost: the pair fit wins over a chosen match.
        turned = f", turned {self.yaw.value():+.0f}°" if self.yaw.value() else ""
        self.ghost.setText(f"Show the other scan under {self.base()[1]}{turned}")
        if not self.ghost.isChecked() or T is None or not s.has_scans:
            for view in self.views.values():
                view.marks.set_ghost(None)
            return
        in_target, in_source = pair_fit.ghosts(
            s.cloud("target"), s.cloud("source"), T, _GHOST_POINTS
        )
        self.views["target"].marks.set_ghost(in_target)
        self.views["source"].marks.set_ghost(in_source)

    def _show_pairs(self) -> None:
        self._fit_pairs()
        self._fill_table()
        self._show_marks()
        if self.pick_button.isChecked():
            self.hint.setText(
                "Now click the same point in the SOURCE view."
                if self._pending is not None
                else "Click a point in the TARGET view (Scans tab)."
            )
        else:
            self.hint.setText("")
        self.use_pairs.setEnabled(self.fit is not None)
        self.save_button.setEnabled(bool(self.pairs))
        self.delete_button.setEnabled(bool(self.pairs))
        self.undo_button.setEnabled(bool(self._undo))
        self._reset_nudge()

    def use_pair_fit(self) -> None:
        if self.fit is not None:
            how = f"{len(self.pairs)} point pairs" + (
                ", levelled" if self.fit.levelled else ""
            )
            self.session.add_manual_pose(self.fit.T_target_source, how)

    def _load_pairs_dialog(self) -> None:
        path, _ = QFileDialog.getOpenFileName(
            self, "Load point pairs", "", "Point pairs (*.csv);;All files (*)"
        )
        if path:
            self.load_pairs(Path(path))

    def _save_pairs_dialog(self) -> None:
        path, _ = QFileDialog.getSaveFileName(
            self, "Save point pairs", "pairs.csv", "Point pairs (*.csv)"
        )
        if path:
            self.save_pairs(Path(path))

    def load_pairs(self, path: Path) -> None:
        """Replace the pairs by those of a pairs CSV file (world coordinates)."""
        from amrst.review.pairs_file import read_pairs

        s = self.session
        if not s.has_scans:
            s.report_error("Open a target and a source scan first (File > Open).")
            return
        try:
            t, src = read_pairs(path)
        except InvalidInput as exc:
            s.report_error(str(exc))
            return
        self._undo.append(list(self.pairs))
        self.pairs = pair_fit.local_pairs(s.cloud("target"), s.cloud("source"), t, src)
        self._saved = list(self.pairs)
        self._pending = None
        self._show_pairs()

    def save_pairs(self, path: Path) -> None:
        """Write the pairs to a pairs CSV file (world coordinates)."""
        from amrst.review.pairs_file import write_pairs

        s = self.session
        if not self.pairs or not s.has_scans:
            return
        t, src = pair_fit.world_pairs(s.cloud("target"), s.cloud("source"), self.pairs)
        try:
            write_pairs(path, t, src)
        except (InvalidInput, OSError) as exc:
            s.report_error(f"Could not write {path}: {exc}")
            return
        self._saved = list(self.pairs)

    # ----------------------------------------------------------- transform
    def _load_dialog(self) -> None:
        path, _ = QFileDialog.getOpenFileName(
            self, "Load a transform", "", "Transform (*.json *.txt);;All files (*)"
        )
        if path:
            self.load_transform(Path(path))

    def load_transform(self, path: Path) -> None:
        """Put a transform file's text in the box (a small file only: a scan picked by
        mistake, or a named pipe, is refused rather than read on the GUI thread)."""
        from amrst.files.safefile import read_small_file

        try:
            data = read_small_file(
                path,
                "transform file",
                "a 4x4 matrix as text, or a transform.json",
                max_bytes=1 << 20,
            )
        except InvalidInput as exc:
            self.session.report_error(str(exc))
            return
        self.text.setPlainText(data.decode("utf-8", errors="replace"))

    def use_typed_transform(self) -> None:
        """Parse the text as a world T_target_source and add it as a candidate."""
        s = self.session
        if not s.has_scans:
            s.report_error("Open a target and a source scan first (File > Open).")
            return
        try:
            T_world = manual.parse_transform(self.text.toPlainText(), "The transform")
        except InvalidInput as exc:
            s.report_error(str(exc))
            return
        s.add_manual_pose(
            local_transform(T_world, s.cloud("target"), s.cloud("source")),
            "typed transform",
        )

    # --------------------------------------------------------------- slots
    def _on_scans_changed(self, *_args) -> None:
        self.pairs, self._saved, self._undo, self._pending = [], [], [], None
        self._score_cache = self._stem_cache = None
        self.set_picking(False)
        self._show_pairs()

    def _on_base_changed(self, *_args) -> None:
        if self.fit is None:
            self._reset_nudge()
