"""RegistrationPane: target and moved source overlaid, before / coarse / fine."""

from __future__ import annotations

import functools

from PySide6.QtWidgets import (
    QButtonGroup,
    QComboBox,
    QLabel,
    QRadioButton,
    QVBoxLayout,
    QWidget,
)

from amrst_gui.pacing import DRAWS
from amrst_gui.views.bar_row import FlowLayout, add_look_buttons, wrapping_row
from amrst_gui.views.framing import LOOKS
from amrst_gui.views.quality_views import DistanceHistogram
from amrst_gui.views.scan_pane import RESULT_SIGNALS
from amrst_gui.views.scan_view import ScanView
from amrst_gui.views.scene import (
    REGISTRATION_STAGES,
    build_registration_scene,
    previewed_candidate,
)
from amrst_gui.views.scene_jobs import SceneLoader, Snapshot

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
        bar = FlowLayout()
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
        self.colour = QComboBox()
        self.colour.addItem("Scan colours", "scans")
        self.colour.addItem("Distance (cm)", "distance")
        self.colour.setToolTip(
            "Colour each point by its distance to the other scan (both ways), with "
            "a histogram under the view: a right pose is blue (under 1-2 cm) "
            "wherever both scans see the tree"
        )
        self.colour.currentIndexChanged.connect(lambda _i: self.refresh())
        bar.addWidget(self.colour)
        add_look_buttons(
            bar,
            {
                "Top": "Look down the stem",
                "Front": "Look along y",
                "Side": "Look along x",
            },
            self.look,
        )
        self.view = ScanView(self)
        self.loader = SceneLoader(self.view, self)
        self.loader.drawn.connect(self._on_drawn)
        self.loader.failed.connect(session.report_error)
        self.histogram = DistanceHistogram(self)
        self.histogram.hide()
        layout = QVBoxLayout(self)
        layout.setContentsMargins(0, 0, 0, 0)
        layout.addWidget(wrapping_row(bar))
        layout.addWidget(self.view, 1)
        layout.addWidget(self.histogram)
        for name in RESULT_SIGNALS:
            slot = getattr(self, f"_on_{name}", self._on_results_changed)
            getattr(session, name).connect(slot)
        session.manual_preview_changed.connect(self._on_manual_preview_changed)
        session.busy_changed.connect(self._on_busy_changed)

    def _on_busy_changed(self, busy: bool) -> None:
        # Idle (a pair loaded, a step done) with the overlay in a hidden tab: its
        # points are drawn once off screen while nothing runs.
        if busy:
            DRAWS.drop(self, "prerender")
        else:
            self._prerender_later()

    def _prerender_later(self) -> None:
        if not self.session.busy and not self.view.isVisible():
            DRAWS.later(self, "prerender", self._prerender)

    def _prerender(self) -> None:
        # The loader's next scene queues this again (``_on_drawn``).
        if self.session.busy or self.view.isVisible() or self.loader.pending:
            return
        if not DRAWS.idle:  # the least urgent draw: every other one goes first
            self._prerender_later()
            return
        self.view.prerender()

    def set_stage(self, stage: str) -> None:
        """Show "before", "coarse" or "fine"."""
        self.buttons.button(REGISTRATION_STAGES.index(stage)).setChecked(True)

    def refresh(self) -> None:
        """Rebuild the overlay from the session and draw it (in a worker for big
        scans: the distance colouring's neighbour queries too)."""
        mode = self.colour.currentData()
        snap = Snapshot(self.session)
        build = functools.partial(
            build_registration_scene, stage=self.stage, colour=mode
        )
        self.loader.request(build, snap, snap.n_points("target", "source"))

    def _on_drawn(self) -> None:
        self._prerender_later()
        scene = self.view.scene
        mode = self.colour.currentData()
        self.histogram.setVisible(mode == "distance")
        self.histogram.set_distances(
            scene.extra.get("distances", []) if scene is not None else [],
            self._headline(),
        )

    def _headline(self) -> str:
        """The shown stage's distances where both scans saw the scene, as measured
        by the registration (its Quality table and metrics.json), or ""."""
        stage = self.stage if self.stage in ("coarse", "fine") else None
        if stage == "coarse" and previewed_candidate(self.session) is not None:
            return ""  # a selected row's preview: nothing measured it yet
        quality = self.session.stage_quality(stage) if stage else None
        if quality is None or quality.overlap.n_points_measured == 0:
            return ""
        d = quality.overlap
        return (
            f"{stage}, both saw: median {d.median_m * 100:.1f} cm, within 2 cm "
            f"{d.within_2cm_fraction:.0%}"
        )

    def look(self, direction: str) -> None:
        """Top, Front or Side view of the whole tree."""
        toward, up = LOOKS[direction]
        self.view.reset_camera(direction=toward, up=up, elevation=0.0)

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
