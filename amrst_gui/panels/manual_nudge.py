"""The Manual dock's nudge: turn the source about the vertical, move it, live score.

A mixin of :class:`~amrst_gui.panels.manual_panel.ManualPanel` (its box, its pose
and its score), so the panel module stays under 400 lines.
"""

from __future__ import annotations

import logging
from typing import TYPE_CHECKING, Any

import numpy as np
from PySide6.QtCore import Qt
from PySide6.QtWidgets import (
    QDoubleSpinBox,
    QGridLayout,
    QGroupBox,
    QLabel,
    QPushButton,
    QSlider,
)

from amrst.review import manual

log = logging.getLogger("amrst_gui.manual")
# The score's target points, thinned evenly to at most this many: its KD-tree is built
# on the GUI thread, in a few tenths of a second whatever the scan's size.
SCORE_TARGET_POINTS = 250_000


class NudgeMixin:
    """Nudge controls and the pose they make."""

    if TYPE_CHECKING:
        session: Any
        fit: manual.PairFit | None
        _score_cache: tuple | None
        _score_stale: bool
        _stem_cache: tuple | None

        def isVisible(self) -> bool: ...

    def _nudge_box(self) -> QGroupBox:
        box = QGroupBox("Nudge the source")
        grid = QGridLayout(box)
        self.yaw = QDoubleSpinBox()
        self.yaw.setRange(-180, 180)
        self.yaw.setSuffix(" °")
        self.yaw.setDecimals(1)
        self.yaw.setToolTip("Turn the source about the vertical through its stem")
        self.yaw_slider = QSlider(Qt.Orientation.Horizontal)
        self.yaw_slider.setRange(-180, 180)
        self.yaw_slider.valueChanged.connect(lambda v: self.yaw.setValue(float(v)))
        self.yaw.valueChanged.connect(self._sync_slider)
        self.yaw.valueChanged.connect(self._on_nudged)
        grid.addWidget(QLabel("Turn:"), 0, 0)
        grid.addWidget(self.yaw, 0, 1)
        grid.addWidget(self.yaw_slider, 0, 2)
        self.shift: list[QDoubleSpinBox] = []
        for i, axis in enumerate("xyz"):
            spin = QDoubleSpinBox()
            spin.setRange(-5000, 5000)
            spin.setSingleStep(5)
            spin.setSuffix(" cm")
            spin.setToolTip(f"Move the source along {axis} (target frame)")
            spin.valueChanged.connect(self._on_nudged)
            grid.addWidget(QLabel(f"Move {axis}:"), 1 + i, 0)
            grid.addWidget(spin, 1 + i, 1)
            self.shift.append(spin)
        self.score_label = QLabel("")
        self.score_label.setObjectName("nudge_score")
        self.score_label.setWordWrap(True)
        self.score_label.setToolTip(
            "Under the nudged pose (no polish): the median distance of sampled source "
            "points to the target (up to 1 m), and their share within 4 cm, which "
            "rises only near the right pose. Where the scans share little the median "
            "can stay flat or lead astray: judge the pose in the overlay and the stem "
            "slices too. Measured on the prepared points once Separate has run, on "
            "all points before: the two read differently."
        )
        self.use_nudge = QPushButton("Use nudged pose")
        self.use_nudge.clicked.connect(self.use_nudged)
        grid.addWidget(self.score_label, 4, 0, 1, 3)
        grid.addWidget(self.use_nudge, 5, 0, 1, 3)
        return box

    def base(self) -> tuple[np.ndarray | None, str]:
        """The pose the nudge starts from and what it is, in a few words: the pair
        fit ("the fit of 3 pairs"), else the shown candidate ("match #2")."""
        if self.fit is not None:
            return (
                self.fit.T_target_source,
                f"the fit of {len(self.fit.residuals_m)} pairs",
            )
        s = self.session
        for cand in (s.selected_match, s.coarse and s.coarse.candidate):
            if cand:
                return np.asarray(cand.T_target_source), f"match #{cand.rank}"
        return None, "no pose yet"

    def nudged_pose(self) -> np.ndarray | None:
        """The base pose turned and moved by the nudge controls."""
        base, _ = self.base()
        if base is None:
            return None
        return manual.nudge(
            base,
            self.yaw.value(),
            (
                self.shift[0].value() / 100,
                self.shift[1].value() / 100,
                self.shift[2].value() / 100,
            ),
            pivot=self._pivot(base),
        )

    def _pivot(self, base: np.ndarray) -> np.ndarray:
        # The source's stem, moved: its lowest metre of points, in the target frame.
        cloud = self.session.cloud("source")
        if cloud is None or not len(cloud):
            return np.zeros(3)
        # Once per source scan, not at every new match list.
        cached = self._stem_cache
        if cached is None or cached[0] is not cloud:
            xyz = cloud.xyz[:: max(1, len(cloud) // 20000)]
            low = xyz[xyz[:, 2] < xyz[:, 2].min() + 1.0]
            cached = self._stem_cache = (cloud, low.mean(axis=0))
        c = cached[1]
        return np.asarray(base[:3, :3] @ c + base[:3, 3])

    def _sync_slider(self, value: float) -> None:
        """The slider follows a typed turn (without turning again)."""
        self.yaw_slider.blockSignals(True)
        self.yaw_slider.setValue(round(value))
        self.yaw_slider.blockSignals(False)

    def _reset_nudge(self) -> None:
        if any(w.value() for w in (self.yaw, *self.shift)):
            log.info("Nudge back to zero: it now moves %s.", self.base()[1])
        for w in (self.yaw, *self.shift):
            w.blockSignals(True)
            w.setValue(0.0)
            w.blockSignals(False)
        self.yaw_slider.blockSignals(True)
        self.yaw_slider.setValue(0)
        self.yaw_slider.blockSignals(False)
        self._on_nudged()

    def _on_nudged(self, *_args) -> None:
        T = self.nudged_pose()
        self.session.set_manual_preview(T)
        self.use_nudge.setEnabled(T is not None)
        if T is None:
            self.score_label.setText("Nothing to nudge yet: pick pairs or match.")
            return
        # Hidden behind another dock tab: scored when shown. The score builds a
        # KD-tree of the target on the GUI thread with every new match list, a
        # stall during Run all that nobody would look at.
        self._score_stale = not self.isVisible()
        if self._score_stale:
            self.score_label.setText("Score of this pose: shown with this tab.")
            return
        median_m, share = self.live_score(T)
        target = self.session.analysis("target") or self.session.cloud("target")
        points = (
            "prepared points"
            if self.session.analysis("target") is not None
            else "all points"
            if len(target.xyz) <= SCORE_TARGET_POINTS
            else f"the target thinned to {SCORE_TARGET_POINTS:,} points"
        )
        self.score_label.setText(
            f"This pose ({points}): median distance of all sampled source points "
            f"{median_m * 100:.1f} cm (not only where both scans saw the scene, as "
            f"the verdict measures), {share:.0%} of them within "
            f"{self.session.params.coarse.tight_dist_m * 100:.0f} cm of the target."
        )

    def live_score(self, T: np.ndarray) -> tuple[float, float]:
        """The nudged pose's median distance (m, up to 1 m) and tight share, on the
        verification's sample: the median changes with every turn, far from the
        right pose too, where the tight share stays near zero."""
        s = self.session
        # The objects themselves, compared by identity: an id() of an object no
        # longer held can come back for a new one (a stale tree). The target's tree
        # and the source's sample are kept apart: a new source keeps the tree.
        tkey = (s.analysis("target"), s.cloud("target"))
        skey = (s.analysis("source"), s.cloud("source"))
        built, sampled = self._score_cache or (None, None)
        if not _made_from(built, tkey):
            from scipy.spatial import cKDTree

            xyz = _points(tkey)
            step = max(1, -(-len(xyz) // SCORE_TARGET_POINTS))  # ceil: at most that
            built = (tkey, cKDTree(xyz[::step]))
        if not _made_from(sampled, skey):
            from amrst.stages.coarse import verification_sample

            sampled = (skey, verification_sample(_points(skey), s.params.coarse)[0])
        self._score_cache = (built, sampled)
        tree, sample = built[1], sampled[1]
        if not len(sample):
            return float("nan"), 0.0
        moved = sample @ T[:3, :3].T + T[:3, 3]
        d = np.minimum(tree.query(moved, distance_upper_bound=1.0)[0], 1.0)
        return float(np.median(d)), float(np.mean(d < s.params.coarse.tight_dist_m))

    def use_nudged(self) -> None:
        T = self.nudged_pose()
        if T is not None:
            self.session.add_manual_pose(T, f"nudged {self.yaw.value():+.1f}°")


def _made_from(entry: tuple | None, key: tuple) -> bool:
    """Whether a cached (key, value) was made from these very objects."""
    return entry is not None and all(a is b for a, b in zip(entry[0], key, strict=True))


def _points(key: tuple) -> np.ndarray:
    """The prepared points of (analysis, cloud), else the cloud's."""
    analysis, cloud = key
    return analysis.xyz if analysis is not None else cloud.xyz
