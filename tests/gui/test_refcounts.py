"""The installed Qt binding keeps Python's reference counts straight.

PySide6 6.12.0 on CPython 3.11 released a reference to ``None`` on every Qt call that
returns nothing and to ``True`` on every ``Signal.emit``; after about 50 registrations
in one session the app aborted with "Fatal Python error: none_dealloc". pyproject.toml
excludes that release; this test fails on any binding that does the same.
"""

from __future__ import annotations

import sys

from PySide6.QtCore import QObject, Signal
from PySide6.QtGui import QAction

CALLS = 200  # small: a broken binding must fail the test, not abort pytest


class _Emitter(QObject):
    progress = Signal(float, str)
    done = Signal(object)


def _counts() -> tuple[int, int]:
    return sys.getrefcount(None), sys.getrefcount(True)


def test_void_qt_calls_and_emits_keep_none_and_true_alive(qapp):
    action = QAction("x")
    emitter = _Emitter()
    emitter.progress.connect(lambda *_: None)
    emitter.done.connect(lambda *_: None)
    none0, true0 = _counts()
    for i in range(CALLS):
        action.setEnabled(i % 2 == 0)
        action.setText("y")
        emitter.progress.emit(0.5, "x")
        emitter.done.emit(None)
    none1, true1 = _counts()
    # On CPython >= 3.12 None and True are immortal and their counts do not move; on
    # 3.11 a correct binding changes them by a handful, a broken one by about CALLS.
    assert none1 - none0 > -CALLS // 4
    assert true1 - true0 > -CALLS // 4
