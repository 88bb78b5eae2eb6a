"""Fixtures for the app tests: Qt set up before QApplication, isolated settings,
a ``make_main_window`` factory that closes every view and checks for leaks.

Run headless with pytest-xvfb and ``QT_QPA_PLATFORM=xcb``: it is the only Qt platform
on which the QtInteractors draw (``offscreen`` does not support their QOpenGLWidget).
"""

from __future__ import annotations

import gc
import os
from pathlib import Path

os.environ.setdefault("QT_API", "pyside6")
os.environ.setdefault("LIBGL_ALWAYS_SOFTWARE", "1")

import numpy as np
import pytest

from amrst_gui.app import configure_qt, sample_dir

# Shared GL contexts and the GL format must be set before pytest-qt makes the app.
configure_qt()


def pytest_collection_modifyitems(items) -> None:
    here = Path(__file__).parent
    for item in items:
        if here in Path(item.fspath).parents:
            item.add_marker(pytest.mark.gui)


@pytest.fixture(autouse=True)
def _isolated_settings(tmp_path):
    """Every test gets its own QSettings folder (never the user's)."""
    from PySide6.QtCore import QSettings

    QSettings.setPath(
        QSettings.IniFormat, QSettings.UserScope, str(tmp_path / "settings")
    )


@pytest.fixture(autouse=True)
def discard_answers(monkeypatch):
    """The discard question never blocks a test: it answers from this list.

    Append False to refuse the next question; every question asked is recorded in
    ``discard_answers.asked``. With the list empty the answer is Discard.
    """
    from amrst_gui import dialogs

    class Answers(list):
        asked: list[str]
        keep: list[str]

    answers = Answers()
    answers.asked = []
    answers.keep = []

    def answer(_parent, action: str, _lost: str, keep: str = "") -> bool:
        answers.asked.append(action)
        answers.keep.append(keep)
        return answers.pop(0) if answers else True

    monkeypatch.setattr(dialogs, "confirm_discard", answer)
    return answers


@pytest.fixture(autouse=True)
def override_answers(monkeypatch):
    """The export-override question never blocks: it answers from this list.

    Append True to export anyway; every verdict asked about is recorded in
    ``override_answers.asked``. With the list empty the answer is Cancel.
    """
    from amrst_gui import dialogs

    class Answers(list):
        asked: list

    answers = Answers()
    answers.asked = []

    def answer(_parent, verdict) -> bool:
        answers.asked.append(verdict)
        return answers.pop(0) if answers else False

    monkeypatch.setattr(dialogs, "confirm_override", answer)
    return answers


@pytest.fixture(autouse=True)
def close_answers(monkeypatch):
    """The Plot window's question before it closes with choices not run answers Close
    (True) unless False is appended; each question is in ``close_answers.asked``."""
    from amrst_gui.plot import window

    class Answers(list):
        asked: list[str]

    answers = Answers()
    answers.asked = []

    def answer(_parent, text: str) -> bool:
        answers.asked.append(text)
        return answers.pop(0) if answers else True

    monkeypatch.setattr(window, "ask_close", answer)
    return answers


@pytest.fixture(autouse=True)
def replace_answers(monkeypatch):
    """The question before replacing another pair's export never blocks: it
    answers from this list (True: Replace); each folder asked about is recorded in
    ``replace_answers.asked``. With the list empty the answer is Cancel."""
    from amrst_gui import dialogs

    class Answers(list):
        asked: list

    answers = Answers()
    answers.asked = []

    def answer(_parent, folder, _before) -> bool:
        answers.asked.append(folder)
        return answers.pop(0) if answers else False

    monkeypatch.setattr(dialogs, "confirm_replace", answer)
    return answers


@pytest.fixture(scope="session")
def sample_pair():
    """The bundled sample: (target, source, truth) paths from resources/sample."""
    folder = sample_dir()
    paths = tuple(folder / n for n in ("target.ply", "source.ply", "truth.json"))
    missing = [p.name for p in paths if not p.is_file()]
    assert not missing, f"bundled sample incomplete in {folder}: missing {missing}"
    return paths


def _close_views(win) -> None:
    for view in win.views():
        view.close_view()


def _open_interactors() -> list:
    from pyvistaqt import QtInteractor

    gc.collect()
    return [
        o
        for o in gc.get_objects()
        if isinstance(o, QtInteractor) and not getattr(o, "_closed", True)
    ]


def _top_level_widgets(qapp) -> list:
    """``qapp.topLevelWidgets()``, widgets only. PySide keeps a wrapper per C++
    address; pyvistaqt holds its context's ``surface()`` (a QSurface, which PySide
    cannot see deleted), so a new window at the address of a deleted surface can
    come back as that stale QSurface wrapper."""
    from PySide6.QtWidgets import QWidget

    return [w for w in qapp.topLevelWidgets() if isinstance(w, QWidget)]


@pytest.fixture
def make_main_window(qtbot, qapp):
    """Factory: ``make_main_window()`` -> a shown MainWindow registered with qtbot.

    At teardown every window is closed (which cancels and waits for a running
    step and closes the plotters first: a QtInteractor must be closed before its
    widget is destroyed, else VTK touches a dead window), then nothing may be
    left: no running job, no open QtInteractor, no new visible top-level widget.
    """
    from amrst_gui.main_window import MainWindow

    before = set(_top_level_widgets(qapp))
    windows = []

    def factory(**kwargs) -> MainWindow:
        win = MainWindow(**kwargs)
        qtbot.addWidget(win, before_close_func=_close_views)
        win.show()
        qtbot.waitExposed(win)
        windows.append(win)
        return win

    yield factory

    for win in windows:
        win.close()
    for win in windows:
        assert not win.session.busy
        assert all(view._closed for view in win.views())
    leaked = [w for w in _top_level_widgets(qapp) if w.isVisible() and w not in before]
    assert not leaked, f"widgets left open: {leaked}"
    assert not _open_interactors(), "a QtInteractor was not closed"


@pytest.fixture
def loaded_window(make_main_window, qtbot, sample_pair):
    """A main window with the sample pair loaded (and its truth)."""
    win = make_main_window()
    target, source, truth = sample_pair
    with qtbot.waitSignals([win.session.scan_loaded] * 2, timeout=20_000):
        win.open_pair(target, source, truth)
    qtbot.waitUntil(lambda: not win.session.busy, timeout=5_000)
    return win


@pytest.fixture
def errors(qtbot):
    """Collects ``session.failed`` messages: ``errors.watch(session)``; assert on it."""

    class Errors(list):
        def watch(self, session):
            session.failed.connect(self.append)
            return self

    return Errors()


@pytest.fixture
def content_fraction():
    """``content_fraction(widget)``: share of its pixels unlike the 3D background."""
    return _content_fraction


def _content_fraction(widget, background=(31, 33, 38), tol: int = 12) -> float:
    from PySide6.QtGui import QImage

    image = widget.grab().toImage().convertToFormat(QImage.Format_RGB888)
    w, h, stride = image.width(), image.height(), image.bytesPerLine()
    buf = np.frombuffer(image.constBits(), np.uint8, count=stride * h).reshape(
        h, stride
    )
    rgb = buf[:, : w * 3].reshape(h, w, 3).astype(int)
    differs = np.abs(rgb - np.array(background)).max(axis=2) > tol
    return float(differs.mean())


@pytest.fixture
def finish(qtbot):
    """``finish(session, trigger, "signal_name")``: run a job to its end.

    Waits for ``busy_changed(False)`` (so a failure ends the wait at once instead
    of timing out), asserts that nothing failed and that the signal came, and
    returns the signal's arguments.
    """

    def run(session, trigger, signal_name: str, timeout: int = 90_000) -> tuple:
        got: list[tuple] = []
        failed: list[str] = []
        signal = getattr(session, signal_name)

        def on_signal(*args):
            got.append(args)

        def on_failed(message):
            failed.append(message)

        signal.connect(on_signal)
        session.failed.connect(on_failed)
        try:
            with qtbot.waitSignal(
                session.busy_changed, timeout=timeout, check_params_cb=lambda b: not b
            ):
                trigger()
        finally:
            signal.disconnect(on_signal)
            session.failed.disconnect(on_failed)
        assert not failed, failed
        assert got, f"{signal_name} was not emitted"
        return got[-1]

    return run


@pytest.fixture(autouse=True)
def opened_reports(monkeypatch):
    """View report never starts a browser in a test: the paths it would open."""
    from amrst_gui import dialogs

    opened: list = []

    def record(_parent, path) -> bool:
        opened.append(path)
        return True

    monkeypatch.setattr(dialogs, "open_report", record)
    return opened


@pytest.fixture(scope="session")
def sample_clouds(sample_pair) -> dict:
    """The bundled sample's two scans, read with amrst.io, by role."""
    from amrst import io

    return {"target": io.read(sample_pair[0]), "source": io.read(sample_pair[1])}


@pytest.fixture(scope="module")
def big_clouds() -> dict:
    """2,000,000 points a scan: jittered copies of the sample, seeded, in memory."""
    import sys

    sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))
    from dense_clouds import dense_cloud

    return {
        "target": dense_cloud(2_000_000),
        "source": dense_cloud(2_000_000, "source"),
    }
