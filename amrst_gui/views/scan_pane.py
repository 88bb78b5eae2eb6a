"""ScanPane (layer toggles + one ScanView) and ScansArea (target | source)."""

from __future__ import annotations

import dataclasses
import functools
from typing import TYPE_CHECKING

from PySide6.QtCore import Qt, Signal
from PySide6.QtWidgets import (
    QCheckBox,
    QComboBox,
    QHBoxLayout,
    QLabel,
    QPushButton,
    QSplitter,
    QVBoxLayout,
    QWidget,
)

from amrst_gui.drops import FileDropMixin
from amrst_gui.views.bar_row import FlowLayout, add_look_buttons, wrapping_row
from amrst_gui.views.framing import LOOKS
from amrst_gui.views.layers import SpheresLayer
from amrst_gui.views.linking import CameraLink
from amrst_gui.views.scan_view import ScanView
from amrst_gui.views.scene import COLOUR_MODES, ViewOptions, build_scan_scene
from amrst_gui.views.scene_jobs import SceneLoader, Snapshot

if TYPE_CHECKING:
    from pathlib import Path

_COLOUR_LABELS = {
    "height": "Height",
    "intensity": "Intensity",
    "wood": "Wood / leaf",
    "scene": "Scene (tree / ground / other)",
}


# Session signals after which what a 3D view shows may differ.
RESULT_SIGNALS = (
    "scan_loaded",
    "scans_swapped",
    "separation_finished",
    "skeletons_finished",
    "matches_changed",
    "review_changed",
    "selection_changed",
    "coarse_accepted",
    "fine_finished",
)


class ScanPane(FileDropMixin, QWidget):
    """Layer toggles above one scan's 3D view.

    Listens to the session's result signals (``scan_loaded``, ``scans_swapped``,
    ``separation_finished``, ``skeletons_finished``, ``matches_changed``,
    ``review_changed``, ``selection_changed``) and redraws; emits
    ``files_dropped(role, paths)`` when scan files are dropped on it.
    """

    files_dropped = Signal(str, list)

    def __init__(self, session, role: str, parent: QWidget | None = None) -> None:
        super().__init__(parent)
        self.setObjectName(f"{role}_pane")
        self.session = session
        self.role = role
        self.options = ViewOptions()
        self.setAcceptDrops(True)

        bar = FlowLayout()
        bar.setContentsMargins(4, 2, 4, 2)
        self.toggles: dict[str, QCheckBox] = {}
        for field, label, tip in (
            ("show_points", "Points", "Show the scan's points"),
            (
                "show_skeleton",
                "Skeleton",
                "Show the skeleton as lines (after Skeleton)",
            ),
            (
                "show_keypoints",
                "Key points",
                "Key points: white root, orange branch, blue end",
            ),
            (
                "show_match",
                "Match",
                "The selected tetrahedron; vertex colours correspond "
                "between the two views",
            ),
        ):
            box = QCheckBox(label)
            box.setChecked(getattr(self.options, field))
            box.setToolTip(tip)
            box.toggled.connect(lambda on, f=field: self._set_option(f, on))
            bar.addWidget(box)
            self.toggles[field] = box
        self.colour = QComboBox()
        for mode in COLOUR_MODES:
            self.colour.addItem(_COLOUR_LABELS[mode], mode)
        self.colour.setToolTip(
            "Colour the points by height, by scanner intensity, or wood (brown) / "
            "leaves (green) after separation"
        )
        self.colour.currentIndexChanged.connect(
            lambda _i: self._set_option("colour", self.colour.currentData())
        )
        colour_box = QWidget()  # the label wraps with its box, never apart
        colour_row = QHBoxLayout(colour_box)
        colour_row.setContentsMargins(0, 0, 0, 0)
        colour_row.addWidget(QLabel("Colour:"))
        colour_row.addWidget(self.colour)
        bar.addWidget(colour_box)

        self.view = ScanView(self)
        self.loader = SceneLoader(self.view, self)
        self.loader.failed.connect(session.report_error)
        layout = QVBoxLayout(self)
        layout.setContentsMargins(0, 0, 0, 0)
        layout.setSpacing(0)
        layout.addWidget(wrapping_row(bar))
        layout.addWidget(self.view, 1)
        for name in RESULT_SIGNALS:
            slot = getattr(self, f"_on_{name}", self._on_results_changed)
            getattr(session, name).connect(slot)

    def set_colour_mode(self, mode: str) -> None:
        """Choose the point colouring ("height", "intensity" or "wood")."""
        self.colour.setCurrentIndex(COLOUR_MODES.index(mode))

    def refresh(self) -> None:
        """Rebuild the scene from the session and draw it (in a worker for a big
        scan: the view keeps its last scene until the new one is ready)."""
        snap = Snapshot(self.session)
        build = functools.partial(
            build_scan_scene, role=self.role, options=self.options
        )
        self.loader.request(build, snap, snap.n_points(self.role))

    def _set_option(self, field: str, value) -> None:
        self.options = dataclasses.replace(self.options, **{field: value})
        self.refresh()

    def _on_results_changed(self, *_args) -> None:
        self.refresh()

    def _on_separation_finished(self) -> None:
        # Show the separation as soon as it exists: that is what the step is for.
        if self.options.colour != "wood":
            self.set_colour_mode("wood")  # refreshes
        else:
            self.refresh()

    def files_dropped_here(self, paths: list[Path]) -> None:
        self.files_dropped.emit(self.role, paths)


class ScansArea(QWidget):
    """Target and source side by side, with optionally linked cameras.

    Listens to the session through its two panes; emits ``files_dropped``.
    """

    files_dropped = Signal(str, list)

    def __init__(self, session, parent: QWidget | None = None) -> None:
        super().__init__(parent)
        self.setObjectName("scans_area")
        self.panes = {
            role: ScanPane(session, role, self) for role in ("target", "source")
        }
        bar = FlowLayout()
        bar.setContentsMargins(4, 2, 4, 0)
        self.link_box = QCheckBox("Link cameras")
        self.link_box.setToolTip(
            "Rotate both views together. Once a coarse solution exists, the source "
            "view turns with the transform, so both show the tree from the same side."
        )
        reset = QPushButton("Reset views")
        reset.setToolTip("Look at both trees from the side again")
        reset.clicked.connect(self.reset_cameras)
        self.frame_button = QPushButton("Frame match")
        self.frame_button.setToolTip(
            "Zoom both views onto the selected tetrahedron (F); Reset views to go back"
        )
        self.frame_button.setShortcut("F")
        self.frame_button.clicked.connect(self.frame_match)
        bar.addWidget(self.link_box)
        bar.addWidget(reset)
        add_look_buttons(
            bar,
            {
                "Top": "Look down both stems: find the same side of the crowns",
                "Side": "Look at both trees along x, level",
            },
            self.look,
        )
        bar.addWidget(self.frame_button)
        splitter = QSplitter(Qt.Orientation.Horizontal)
        for pane in self.panes.values():
            splitter.addWidget(pane)
            pane.files_dropped.connect(self.files_dropped)
        layout = QVBoxLayout(self)
        layout.setContentsMargins(0, 0, 0, 0)
        layout.addWidget(wrapping_row(bar))
        layout.addWidget(splitter, 1)
        self.link = CameraLink(
            session, self.panes["target"].view, self.panes["source"].view
        )
        self.link_box.toggled.connect(self.link.set_enabled)

    def views(self) -> list[ScanView]:
        """The two scan views."""
        return [pane.view for pane in self.panes.values()]

    def refresh(self) -> None:
        """Redraw both panes from the session."""
        for pane in self.panes.values():
            pane.refresh()

    def reset_cameras(self) -> None:
        """Side views of both trees."""
        for view in self.views():
            view.reset_camera()

    def look(self, direction: str) -> None:
        """Top or Side view of both trees, level (framing.LOOKS)."""
        toward, up = LOOKS[direction]
        for view in self.views():
            view.reset_camera(direction=toward, up=up, elevation=0.0)

    def frame_match(self) -> None:
        """Zoom each view onto its tetrahedron of the selected match."""
        for view in self.views():
            layers = view.scene.layers if view.scene is not None else ()
            for layer in layers:
                if layer.name == "match_vertices":
                    # build_scan_scene makes match_vertices a SpheresLayer only.
                    assert isinstance(layer, SpheresLayer)
                    # Keep some of the tree around a small tetrahedron in sight.
                    view.frame_points(layer.centers, min_radius=6 * layer.radius)
