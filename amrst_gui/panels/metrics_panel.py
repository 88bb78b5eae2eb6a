"""MetricsPanel: coarse and fine quality numbers, truth errors, time per stage."""

from __future__ import annotations

import math

from PySide6.QtGui import QColor
from PySide6.QtWidgets import (
    QHeaderView,
    QLabel,
    QTableWidget,
    QTableWidgetItem,
    QTabWidget,
    QVBoxLayout,
    QWidget,
)

from amrst.results.metric_doc import METRIC_ROWS
from amrst.review.strength import AXES, WEAK_STRENGTH
from amrst_gui import steps
from amrst_gui.panels.verdict_style import verdict_style

_STAGES = ("coarse", "fine")
# Where both scans saw the scene: the figures to judge a pose by, first.
_OVERLAP_ROWS: tuple[tuple[str, str, str, str], ...] = (
    (
        "both_median_m",
        "Median dist. (both saw)",
        "cm",
        "Median distance from the moved source to the target where both scans saw "
        "the scene (voxels both occupy, above the ground). Good: under 1.5 cm.",
    ),
    (
        "both_within_2cm",
        "Within 2 cm (both saw)",
        "%",
        "Share of those points within 2 cm of the target. Good: 60% or more.",
    ),
    (
        "both_p95_m",
        "95th pct. (both saw)",
        "cm",
        "95% of the points both scans saw lie closer than this to the target.",
    ),
)
_TRUTH = tuple(
    r for r in METRIC_ROWS if r[0].startswith(("rotation_err", "transl"))
) + (tuple(r for r in METRIC_ROWS if r[0] in ("gt_rmse_m", "registered")))
# Overlap figures, then the truth (above the fold on a laptop), then the rest: the
# figures over every point last, since parts one scan alone saw inflate them.
_ROWS = _OVERLAP_ROWS + _TRUTH + tuple(r for r in METRIC_ROWS if r not in _TRUTH)
# Rows that describe the ICP's own run: blank when Fine's result was dropped.
_ICP_KEYS = ("iterations", "fitness", "inlier_rmse_m", "converged")
_AXIS_NAMES = {
    "tx": "Shift along x",
    "ty": "Shift along y",
    "tz": "Height (z)",
    "rx": "Tilt about x",
    "ry": "Tilt about y",
    "rz": "Turn about the stem (z)",
}
_SCANS = ("target", "source", "merged")
# Tree tab rows: key of TreeMeasures.as_dict(), label, scale to the unit, decimals
# shown, tooltip.
_TREE_ROWS = (
    ("height_m", "Height (m)", 1.0, 2, "Top minus base, stray points left out"),
    ("dbh_m", "DBH (cm)", 100.0, 1, "Stem diameter at breast height"),
    (
        "stem_arc_deg",
        "Stem seen over (°)",
        1.0,
        0,
        "How much of the stem's circumference the DBH circle rests on: one scan sees "
        "about half; the merged tree should see most of it",
    ),
    ("stem_rmse_m", "Stem fit RMSE (mm)", 1000.0, 1, "Bark scatter about the circle"),
    ("crown_width_m", "Crown width (m)", 1.0, 2, "Mean of the two principal widths"),
    ("crown_area_m2", "Crown area (m²)", 1.0, 1, "Convex hull seen from above"),
)


def _fmt(value, kind: str = "") -> str:
    """One format per kind of quantity: cm with 2 decimals, % whole, ° 3 decimals."""
    if value is None:
        return ""
    if isinstance(value, bool):
        return "yes" if value else "NO"
    if isinstance(value, int) and kind in ("count", ""):
        return str(value)
    value = float(value)
    if math.isnan(value):
        return "n/a"
    if kind == "cm":
        cm = value * 100
        return f"{cm:.2f} cm" if abs(cm) < 100 else f"{value:.2f} m"
    if kind == "%":
        return f"{value:.0%}"
    if kind == "deg":
        return f"{value:.3f}°"
    return f"{value:g}"


class MetricsPanel(QWidget):
    """Quality of the coarse and the fine result, truth errors, timings.

    Listens to ``coarse_accepted``, ``fine_finished``, ``review_changed``,
    ``truth_loaded``, ``params_changed`` and the upstream result signals; emits
    nothing. A column whose result is stale says so in its header.
    """

    def __init__(self, session, parent=None) -> None:
        super().__init__(parent)
        self.setObjectName("metrics_panel")
        self.setMinimumWidth(280)
        self.session = session
        self.table = QTableWidget(len(_ROWS), len(_STAGES))
        self.table.setHorizontalHeaderLabels(["Coarse", "Fine"])
        self.table.setVerticalHeaderLabels([label for _, label, _, _ in _ROWS])
        for i, (_, _, _, tip) in enumerate(_ROWS):
            self.table.verticalHeaderItem(i).setToolTip(tip)
        self.table.horizontalHeader().setSectionResizeMode(
            QHeaderView.ResizeMode.Stretch
        )
        # Two value columns fit beside the labels in a 330 px dock (1366x768).
        self.table.horizontalHeader().setMinimumSectionSize(64)
        self.table.setEditTriggers(QTableWidget.EditTrigger.NoEditTriggers)
        self.timings = QTableWidget(0, 1)
        self.timings.setHorizontalHeaderLabels(["Seconds"])
        self.timings.horizontalHeader().setSectionResizeMode(
            QHeaderView.ResizeMode.Stretch
        )
        self.timings.setEditTriggers(QTableWidget.EditTrigger.NoEditTriggers)
        self.tree_table = QTableWidget(len(_TREE_ROWS), len(_SCANS))
        self.tree_table.setObjectName("tree_table")
        self.tree_table.setHorizontalHeaderLabels(["Target", "Source", "Merged"])
        self.tree_table.setVerticalHeaderLabels([row[1] for row in _TREE_ROWS])
        for i, row in enumerate(_TREE_ROWS):
            self.tree_table.verticalHeaderItem(i).setToolTip(row[4])
        self.tree_table.horizontalHeader().setSectionResizeMode(
            QHeaderView.ResizeMode.Stretch
        )
        self.tree_table.setEditTriggers(QTableWidget.EditTrigger.NoEditTriggers)
        self.tree_note = QLabel("")
        self.tree_note.setWordWrap(True)
        tree_page = QWidget()
        tree_layout = QVBoxLayout(tree_page)
        tree_layout.setContentsMargins(0, 0, 0, 0)
        tree_layout.addWidget(self.tree_table, 1)
        tree_layout.addWidget(self.tree_note)
        self.truth_label = QLabel("")
        self.truth_label.setWordWrap(True)
        for table in (self.table, self.timings, self.tree_table):
            table.verticalHeader().setDefaultSectionSize(22)
        self.tabs = QTabWidget()
        self.strength_table = QTableWidget(len(AXES), len(_STAGES))
        self.strength_table.setObjectName("strength_table")
        self.strength_table.setHorizontalHeaderLabels(["Coarse", "Fine"])
        self.strength_table.setVerticalHeaderLabels([_AXIS_NAMES[a] for a in AXES])
        self.strength_table.horizontalHeader().setSectionResizeMode(
            QHeaderView.ResizeMode.Stretch
        )
        self.strength_table.setEditTriggers(QTableWidget.EditTrigger.NoEditTriggers)
        self.strength_table.setToolTip(
            "How firmly the pose holds each axis (0-1, from the final alignment's "
            "normal equations, as Cyclone's strength): 1 when the surfaces face "
            f"along it, under {WEAK_STRENGTH:g} weak (they slide: a bare stem turns "
            "freely about itself). Check the stem slices when an axis is weak."
        )
        self.strength_table.verticalHeader().setDefaultSectionSize(22)
        self.tabs.addTab(self.table, "Quality")
        self.tabs.addTab(self.strength_table, "Strength")
        self.tabs.addTab(tree_page, "Tree")
        self.tabs.addTab(self.timings, "Time per stage")
        self.tabs.currentChanged.connect(self._show_weak)
        layout = QVBoxLayout(self)
        layout.setContentsMargins(2, 2, 2, 2)
        self.verdict_label = QLabel("")
        self.verdict_label.setObjectName("metrics_verdict")
        self.verdict_label.setWordWrap(True)
        layout.addWidget(self.verdict_label)
        layout.addWidget(self.tabs, 1)
        layout.addWidget(self.truth_label)
        for name in (
            "scan_loaded",
            "scans_swapped",
            "separation_finished",
            "skeletons_finished",
            "matches_changed",
            "review_changed",
            "coarse_accepted",
            "fine_finished",
            "truth_loaded",
            "params_changed",
        ):
            getattr(session, name).connect(self._on_results_changed)
        self.refresh()

    def values(self) -> dict[str, dict[str, object]]:
        """What the table shows: stage -> metric -> value."""
        s = self.session
        out: dict[str, dict[str, object]] = {stage: {} for stage in _STAGES}
        for stage, m in s.metrics.items():
            out[stage].update(m.as_dict())
            quality = s.stage_quality(stage)
            if quality is not None:
                d = quality.overlap
                out[stage].update(
                    both_median_m=d.median_m,
                    both_within_2cm=d.within_2cm_fraction,
                    both_p95_m=d.p95_m,
                )
        coarse = s.accepted_coarse or s.coarse
        if coarse is not None:
            out["coarse"]["confidence"] = float(coarse.confidence)
        if s.fine is not None and not s.fine_dropped:
            f = s.fine
            out["fine"].update(
                iterations=int(f.iterations),
                fitness=float(f.fitness),
                inlier_rmse_m=float(f.inlier_rmse_m),
                converged=bool(f.converged),
            )
        for stage, err in s.truth_errors().items():
            out[stage].update(err.as_dict())
            out[stage]["registered"] = bool(err.registered())
        return out

    def refresh(self) -> None:
        """Show the session's current numbers."""
        values = self.values()
        dropped = self.session.fine_dropped
        for col, stage in enumerate(_STAGES):
            for row, (key, _, kind, tip) in enumerate(_ROWS):
                text = _fmt(values[stage].get(key), kind)
                if dropped and stage == "fine" and key in _ICP_KEYS:
                    text, tip = "dropped", self.session.fine_note or tip
                item = QTableWidgetItem(text)
                item.setToolTip(tip)
                self.table.setItem(row, col, item)
        self._show_strength()
        verdict = self.session.verdict
        if verdict is None:
            self.verdict_label.setText("Verdict: none yet (run Match or Run all).")
            self.verdict_label.setStyleSheet("")
        else:
            self.verdict_label.setText(
                f"<b>Verdict: {verdict.headline}.</b> {verdict.reason}"
            )
            self.verdict_label.setStyleSheet(verdict_style(verdict.status))
            self.verdict_label.setToolTip(verdict.text())
        s = self.session
        # A result the current parameters or review no longer describe says so.
        self.table.setHorizontalHeaderLabels(
            [
                f"{title} (stale)" if s.is_stale(stage) else title
                for title, stage in (("Coarse", "coarse"), ("Fine", "fine"))
            ]
        )
        if s.truth is None:
            self.truth_label.setText(
                "No truth loaded (File > Load truth… for true errors)."
            )
        else:
            name = s.truth_path.name if s.truth_path else "truth"
            self.truth_label.setText(f"Truth: {name}")
        self._show_tree()
        timings = self._timings()
        self.timings.setRowCount(len(timings))
        self.timings.setVerticalHeaderLabels(list(timings))
        for row, seconds in enumerate(timings.values()):
            self.timings.setItem(row, 0, QTableWidgetItem(f"{seconds:.2f}"))

    def strength_values(self) -> dict[str, dict[str, float]]:
        """What the Strength tab shows: stage -> axis -> strength (0-1)."""
        out: dict[str, dict[str, float]] = {}
        for stage in _STAGES:
            quality = self.session.stage_quality(stage)
            out[stage] = {} if quality is None else dict(quality.strength.values)
        return out

    def _show_strength(self) -> None:
        """Fill the Strength tab; its title counts the weak axes.

        The tab shows fewer rows than axes on a small screen, and the verdict names a
        weak axis: the tab and the row it names must be found without scrolling
        (:meth:`_show_weak`).
        """
        weak_items = []
        for col, (stage, values) in enumerate(self.strength_values().items()):
            for row, axis in enumerate(AXES):
                v = values.get(axis)
                weak = v is not None and math.isfinite(v) and v < WEAK_STRENGTH
                text = "" if v is None else ("n/a" if math.isnan(v) else f"{v:.2f}")
                item = QTableWidgetItem(text + ("  weak" if weak else ""))
                if weak:
                    item.setForeground(QColor(200, 40, 40))
                    item.setToolTip(
                        f"{_AXIS_NAMES[axis]} is poorly held by the {stage} pose: "
                        "check the stem slices before accepting."
                    )
                    weak_items.append(item)
                self.strength_table.setItem(row, col, item)
        rows = {self.strength_table.row(item) for item in weak_items}
        title = f"Strength ({len(rows)} weak)" if rows else "Strength"
        self.tabs.setTabText(self.tabs.indexOf(self.strength_table), title)
        self._show_weak()

    def _show_weak(self) -> None:
        """Scroll the Strength tab, when shown, to its topmost weak row.

        A hidden table has no height to scroll in: it scrolls when its tab is opened.
        """
        table = self.strength_table
        if self.tabs.currentWidget() is not table:
            return
        weak = [
            item
            for row in range(table.rowCount())
            for col in range(table.columnCount())
            if (item := table.item(row, col)) is not None
            and item.text().endswith("weak")
        ]
        if weak:
            table.scrollToItem(weak[0])

    def tree_values(self) -> dict[str, dict[str, float]]:
        """What the Tree tab shows: scan -> row key -> value in the row's unit."""
        tree = self.session.tree
        out: dict[str, dict[str, float]] = {}
        for scan in _SCANS:
            values = tree[scan].as_dict() if scan in tree else {}
            out[scan] = {
                key: float(values[key]) * scale
                for key, _, scale, _, _ in _TREE_ROWS
                if isinstance(values.get(key), (int, float))
            }
        return out

    def _show_tree(self) -> None:
        values = self.tree_values()
        for col, scan in enumerate(_SCANS):
            for row, (key, _, _, decimals, _) in enumerate(_TREE_ROWS):
                value = values[scan].get(key)
                text = "" if value is None else f"{value:.{decimals}f}"
                self.tree_table.setItem(row, col, QTableWidgetItem(text))
        from amrst.measure import dbh_check

        tree = self.session.tree
        merged = tree.get("merged")
        doubt = dbh_check(tree) if merged is not None else ""
        if doubt:
            row = [r[0] for r in _TREE_ROWS].index("dbh_m")
            item = self.tree_table.item(row, _SCANS.index("merged"))
            assert item is not None  # set just above
            item.setText(f"⚠ {item.text()}")
            item.setForeground(QColor(200, 40, 40))
            item.setToolTip(f"Doubtful DBH: {doubt}.")
        self.tree_note.setStyleSheet("color: #c62828;" if doubt else "")
        if merged is None:
            self.tree_note.setText(
                "Measured once a coarse solution is accepted (and again after fine)."
            )
        else:
            stage = "fine" if self.session.fine is not None else "coarse"
            self.tree_note.setText(
                self._plot_note()
                + (f"Doubtful DBH: {doubt}. " if doubt else "")
                + f"Under the {stage} transform. "
                + (merged.note or "")
            )

    def _plot_note(self) -> str:
        """Say so when the scans hold a plot: the figures are one stem's of many."""
        from amrst.stages.scene import plot_stems, stem_counts

        analyses = [self.session.analysis(role) for role in ("target", "source")]
        stems = plot_stems(
            stem_counts(None if a is None else a.scene for a in analyses)
        )
        if stems is None:
            return ""
        return (
            f"The scans hold {stems[0]} and {stems[1]} stems: a plot, not one tree; "
            "these are the figures of the stem nearest the middle. File ▸ Open plot… "
            "lists and measures every tree. "
        )

    def _timings(self) -> dict[str, float]:
        s = self.session
        out: dict[str, float] = {}
        for step, seconds in s.timings.items():
            out["Load" if step == "load" else steps.plain_label(step)] = seconds
        # The engine's own split of the steps, per scan.
        for role in ("target", "source"):
            an = s.analysis(role)
            for stage, t in (an.timings if an is not None else {}).items():
                out[f"  {role}: {stage}"] = t
        if s.match_result is not None:
            for stage, t in s.match_result.timings.items():
                out[f"  {stage}"] = t
        return out

    def _on_results_changed(self, *_args) -> None:
        self.refresh()
