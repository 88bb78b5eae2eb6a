"""WorkflowStatusBar: the running step, its progress, Cancel, and the last outcome."""

from __future__ import annotations

from PySide6.QtCore import QSize, Qt
from PySide6.QtGui import QPainter
from PySide6.QtWidgets import QLabel, QProgressBar, QPushButton, QStatusBar, QWidget

from amrst_gui import steps
from amrst_gui.panels.verdict_style import ERROR_STYLE, verdict_style


class ElidedLabel(QLabel):
    """A one-line label that ends in "…" when its text does not fit (never cut off).

    ``text()`` stays the whole message; the tooltip shows it too.
    """

    def minimumSizeHint(self) -> QSize:
        return QSize(80, super().minimumSizeHint().height())

    def sizeHint(self) -> QSize:
        return QSize(200, super().sizeHint().height())

    def shown_text(self) -> str:
        """The text as drawn: elided to the label's width."""
        return self.fontMetrics().elidedText(
            " ".join(self.text().split()), Qt.TextElideMode.ElideRight, self.width()
        )

    def paintEvent(self, _event) -> None:
        p = QPainter(self)
        p.setPen(self.palette().color(self.foregroundRole()))
        p.drawText(
            self.rect(),
            int(Qt.AlignmentFlag.AlignVCenter | Qt.AlignmentFlag.AlignLeft),
            self.shown_text(),
        )
        p.end()


class WorkflowStatusBar(QStatusBar):
    """Progress and Cancel while a job runs; the last success or failure after.

    Listens to ``step_started``, ``progressed``, ``busy_changed``, ``failed``,
    ``cancelled`` and the step result signals; calls ``session.cancel()``.
    """

    def __init__(self, session, parent: QWidget | None = None) -> None:
        super().__init__(parent)
        self.setObjectName("status_bar")
        self.session = session
        self._rejected: set[int] = set()  # the rejections the bar last spoke of
        self.message = ElidedLabel("Ready.")
        self.progress = QProgressBar()
        self.progress.setRange(0, 1000)
        self.progress.setMaximumWidth(260)
        self.progress.setTextVisible(True)
        self.progress.setFormat("%p%")
        self.cancel_button = QPushButton("Cancel")
        self.cancel_button.setToolTip(
            "Stop the running step (Esc); earlier results are kept"
        )
        self.cancel_button.clicked.connect(session.cancel)
        self.addWidget(self.message, 1)
        self.addPermanentWidget(self.progress)
        self.addPermanentWidget(self.cancel_button)
        self._on_busy_changed(False)
        session.step_started.connect(self._on_step_started)
        session.progressed.connect(self._on_progressed)
        session.busy_changed.connect(self._on_busy_changed)
        session.failed.connect(self._on_failed)
        session.cancelled.connect(self._on_cancelled)
        session.scan_loaded.connect(self._on_scan_loaded)
        session.separation_finished.connect(self._on_separation_finished)
        session.skeletons_finished.connect(self._on_skeletons_finished)
        session.matches_changed.connect(self._on_matches_changed)
        session.review_changed.connect(self._on_review_changed)
        session.coarse_accepted.connect(self._on_coarse_accepted)
        session.fine_finished.connect(self._on_fine_finished)
        session.exported.connect(self._on_exported)

    def show_message(self, text: str, error: bool = False, detail: str = "") -> None:
        """Put ``text`` in the status bar, red for errors; ``detail`` in the tooltip.

        Text too long for the bar ends in "…"; the tooltip always holds all of it.
        """
        self.message.setStyleSheet(ERROR_STYLE if error else "")
        self.message.setText(text)
        self.message.setToolTip(f"{text}\n\n{detail}" if detail else text)

    def _on_step_started(self, step: str) -> None:
        label = "Loading scans" if step == "load" else steps.plain_label(step)
        self.show_message(f"{label}…")
        self._set_progress(0)

    def _set_progress(self, value: int) -> None:
        # QProgressBar.setValue repaints at once, and with the 3D views in the
        # window every repaint composes the whole window; many reports per second
        # would freeze it. So the value changes with updates off, and the bar is
        # painted with the next frame.
        self.progress.setUpdatesEnabled(False)
        self.progress.setValue(value)
        self.progress.setUpdatesEnabled(True)
        self.progress.update()

    def _on_progressed(self, fraction: float, message: str) -> None:
        self._set_progress(int(fraction * 1000))
        if message:
            step = self.session.running_step or ""
            label = (
                "Loading" if step == "load" else steps.plain_label(step) if step else ""
            )
            self.show_message(f"{label}: {message}" if label else message)

    def _on_busy_changed(self, busy: bool) -> None:
        self.progress.setVisible(busy)
        self.cancel_button.setVisible(busy)
        self.cancel_button.setEnabled(busy)

    def _on_failed(self, message: str) -> None:
        self.show_message(message, error=True)

    def _on_cancelled(self, message: str) -> None:
        self.show_message(message)

    def _on_scan_loaded(self, _role: str) -> None:
        if self.session.has_scans and not self.session.busy:
            dropped = self.session.dropped_truth
            self.show_message(
                "Scans loaded. Next: Separate (Ctrl+1) or Run all (Ctrl+R)."
                + (
                    f" The truth {dropped} was dropped (it belonged to the scans "
                    "open before): load this pair's with File ▸ Load truth."
                    if dropped
                    else ""
                )
            )

    def _on_separation_finished(self) -> None:
        self.show_message(
            "Wood (brown) and leaves (green) separated. "
            "Next: Skeleton & key points (Ctrl+2)."
        )

    def _on_skeletons_finished(self) -> None:
        self.show_message("Skeletons and key points ready. Next: Match (Ctrl+3).")

    def _on_matches_changed(self) -> None:
        self._rejected = set(self.session.rejected)
        n = len(self.session.matches)
        self._show_verdict(
            f"{n} candidate{'s' if n != 1 else ''}. Review them in the Matches dock, "
            "then Accept coarse (Ctrl+4)."
        )

    def _on_review_changed(self, rejected) -> None:
        # A rejection can take the result's candidate away: the verdict changes.
        # Accept coarse says the review changed too; the bar speaks for rejections.
        if set(rejected) == self._rejected:
            return
        self._rejected = set(rejected)
        n = len(self.session.matches)
        self._show_verdict(
            f"{len(rejected)} of {n} candidate{'s' if n != 1 else ''} rejected."
        )

    def _on_coarse_accepted(self, _coarse) -> None:
        self._show_verdict("Coarse solution accepted.")

    def _on_fine_finished(self, fine) -> None:
        # The ICP's own inlier RMSE, named so; the Metrics dock names the others.
        note = self.session.fine_note
        if self.session.stored is not None:  # a campaign tree: nothing ran
            self._show_verdict(f"Stored result of {self.session.stored.label}.")
            return
        if "kept" in note:  # Fine left a manual pose: the technician must know
            self._show_verdict("Fine: your manual pose is kept.", note)
            return
        self._show_verdict(
            f"Fine registration: {fine.iterations} ICP iterations, ICP inlier RMSE "
            f"{fine.inlier_rmse_m * 100:.2f} cm.",
            note,
        )

    def _show_verdict(self, prefix: str, note: str = "") -> None:
        if self.session.busy:
            return  # a chain of steps: the last one speaks
        verdict = self.session.verdict
        if verdict is None:
            self.show_message(prefix)
            return
        # Short in the bar; the reason and the next step in the tooltip (and in the
        # Matches and Metrics docks).
        detail = verdict.text().replace(". ", ".\n")
        self.show_message(
            f"{prefix} {verdict.headline}.",
            detail=f"{note}\n\n{detail}" if note else detail,
        )
        self.message.setStyleSheet(verdict_style(verdict.status))

    def _on_exported(self, paths: list) -> None:
        folder = paths[0].parent if paths else ""
        report = any(p.name == "report.html" for p in paths)
        self.show_message(
            f"Exported {len(paths)} files to {folder}."
            + (" View the report: File > View report." if report else ""),
            detail="\n".join(str(p) for p in paths),
        )
