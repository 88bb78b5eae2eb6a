"""LogPanel: what ran, with which parameters and how long; warnings and errors."""

from __future__ import annotations

import contextlib
import html
import logging
import time

from PySide6.QtCore import QObject, Signal
from PySide6.QtWidgets import (
    QComboBox,
    QHBoxLayout,
    QPlainTextEdit,
    QPushButton,
    QVBoxLayout,
    QWidget,
)

LOGGERS = ("amrst", "amrst_gui")
_COLOURS = {
    logging.DEBUG: "#888888",
    logging.INFO: "#202020",
    logging.WARNING: "#b06000",
    logging.ERROR: "#c00000",
    logging.CRITICAL: "#c00000",
}


class _Relay(QObject):
    record = Signal(int, str)


class QtLogHandler(logging.Handler):
    """A logging handler that forwards records to the GUI thread through a signal.

    Records may come from worker threads (the engine logs while it runs); the
    signal is delivered queued to the panel, which lives on the GUI thread.
    """

    def __init__(self) -> None:
        super().__init__(level=logging.INFO)
        self.relay = _Relay()
        self.setFormatter(logging.Formatter("%(message)s"))

    def emit(self, record: logging.LogRecord) -> None:
        # RuntimeError: the panel is gone (window closed while a worker logs).
        with contextlib.suppress(RuntimeError):
            self.relay.record.emit(record.levelno, self.format(record))


class LogPanel(QWidget):
    """Shows log records of the ``amrst`` (engine) and ``amrst_gui`` loggers.

    Listens to no session signal directly: the session logs what ran, its
    parameters and timings; failures arrive as ERROR records. Call
    ``detach()`` before the window closes.
    """

    def __init__(self, parent: QWidget | None = None) -> None:
        super().__init__(parent)
        self.setObjectName("log_panel")
        self.text = QPlainTextEdit(self)
        self.text.setReadOnly(True)
        self.text.setMaximumBlockCount(5000)
        self.level = QComboBox()
        for label, level in (
            ("All", logging.INFO),
            ("Warnings and errors", logging.WARNING),
            ("Errors", logging.ERROR),
        ):
            self.level.addItem(label, level)
        self.level.setToolTip("Which messages to show from now on")
        clear = QPushButton("Clear")
        clear.setToolTip("Empty the log view (the messages stay in the console log)")
        clear.clicked.connect(self.text.clear)
        bar = QHBoxLayout()
        bar.addWidget(self.level)
        bar.addStretch(1)
        bar.addWidget(clear)
        layout = QVBoxLayout(self)
        layout.setContentsMargins(2, 2, 2, 2)
        layout.addLayout(bar)
        layout.addWidget(self.text)
        self.records: list[tuple[int, str]] = []
        self.handler = QtLogHandler()
        self.handler.relay.record.connect(self._on_record)
        for name in LOGGERS:
            logger = logging.getLogger(name)
            if logger.level == logging.NOTSET or logger.level > logging.INFO:
                logger.setLevel(logging.INFO)
            logger.addHandler(self.handler)

    def detach(self) -> None:
        """Stop receiving records (window closing)."""
        for name in LOGGERS:
            logging.getLogger(name).removeHandler(self.handler)

    def plain_text(self) -> str:
        """Everything shown, as plain text."""
        return self.text.toPlainText()

    def _on_record(self, level: int, message: str) -> None:
        self.records.append((level, message))
        if level < self.level.currentData():
            return
        stamp = time.strftime("%H:%M:%S")
        colour = _COLOURS.get(level, "#202020")
        prefix = {logging.WARNING: "Warning: ", logging.ERROR: "Error: "}.get(level, "")
        body = html.escape(prefix + message).replace("\n", "<br>")
        self.text.appendHtml(f'<span style="color:{colour}">{stamp} {body}</span>')
