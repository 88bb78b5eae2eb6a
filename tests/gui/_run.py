"""Drive a Session without widgets: start work, spin an event loop until idle."""

from __future__ import annotations

from PySide6.QtCore import QEventLoop, QTimer


def run_until_idle(session, start, timeout_ms: int = 90_000) -> list[str]:
    """Call ``start()``, wait until the session is idle again; return its failures.

    Spins ``QEventLoop.exec`` (not ``processEvents`` in a loop) and asserts that the
    session did not time out.
    """
    loop = QEventLoop()
    errors: list[str] = []
    session.failed.connect(errors.append)
    session.busy_changed.connect(lambda busy: None if busy else loop.quit())
    QTimer.singleShot(timeout_ms, loop.quit)
    start()
    if session.busy:
        loop.exec()
    session.failed.disconnect(errors.append)
    assert not session.busy, "timed out"
    return errors
