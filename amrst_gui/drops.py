"""Accepting scan files dropped from a file manager (one behaviour for every widget)."""

from __future__ import annotations

from pathlib import Path


class FileDropMixin:
    """For a QWidget with ``setAcceptDrops(True)``: accepts drags carrying URLs and
    hands the dropped local files to ``files_dropped_here(paths)``."""

    def files_dropped_here(self, paths: list[Path]) -> None:
        raise NotImplementedError

    def dragEnterEvent(self, event) -> None:
        if event.mimeData().hasUrls():
            event.acceptProposedAction()

    def dropEvent(self, event) -> None:
        paths = [
            Path(u.toLocalFile()) for u in event.mimeData().urls() if u.isLocalFile()
        ]
        if paths:
            self.files_dropped_here(paths)
            event.acceptProposedAction()
