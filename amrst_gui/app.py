"""Application set-up: GL format and shared contexts before QApplication, settings,
window sizes."""

from __future__ import annotations

import os
from pathlib import Path
from typing import cast

from PySide6.QtCore import QCoreApplication, QSettings, Qt
from PySide6.QtGui import QSurfaceFormat
from PySide6.QtWidgets import QApplication, QWidget

from amrst.resources import resource_path

ORGANIZATION = "AMRST"
APPLICATION = "AMRST Studio"
FRAME_PX = 40  # a window manager's title bar and frame, left free by fit_screen


def sample_dir() -> Path:
    """The bundled sample pair (resources/sample); AMRST_SAMPLE_DIR overrides it."""
    override = os.environ.get("AMRST_SAMPLE_DIR")
    if override:
        return Path(override)
    return resource_path("sample")


def gl_format() -> QSurfaceFormat:
    """Desktop OpenGL 3.2 core, what VTK's shaders need (as pyvistaqt's rwi asks)."""
    fmt = QSurfaceFormat()
    fmt.setRenderableType(QSurfaceFormat.RenderableType.OpenGL)
    fmt.setProfile(QSurfaceFormat.OpenGLContextProfile.CoreProfile)
    fmt.setVersion(3, 2)
    fmt.setSwapBehavior(QSurfaceFormat.SwapBehavior.DoubleBuffer)
    for size in ("Red", "Green", "Blue", "Alpha"):
        getattr(fmt, f"set{size}BufferSize")(8)
    fmt.setDepthBufferSize(8)
    fmt.setStencilBufferSize(0)
    fmt.setSamples(0)
    return fmt


def configure_qt() -> None:
    """Settings that only work before the QApplication exists.

    Without shared GL contexts a dock holding a QtInteractor froze after being
    floated and docked again.
    """
    os.environ.setdefault("QT_API", "pyside6")
    QCoreApplication.setAttribute(Qt.ApplicationAttribute.AA_ShareOpenGLContexts)
    QSurfaceFormat.setDefaultFormat(gl_format())
    QCoreApplication.setOrganizationName(ORGANIZATION)
    QCoreApplication.setApplicationName(APPLICATION)


def create_app(argv: list[str] | None = None) -> QApplication:
    """The QApplication, configured; reuses an existing one (tests)."""
    existing = QApplication.instance()
    if existing is None:
        configure_qt()
        return QApplication(argv if argv is not None else [])
    # instance() is typed QCoreApplication; the app only ever creates QApplication.
    return cast("QApplication", existing)


def app_settings() -> QSettings:
    """Per-user INI settings; tests redirect them with ``QSettings.setPath``."""
    return QSettings(
        QSettings.Format.IniFormat, QSettings.Scope.UserScope, ORGANIZATION, APPLICATION
    )


def fit_screen(window: QWidget, width: int, height: int) -> None:
    """Size ``window`` to width x height, or maximise it where that does not fit.

    Maximised, not resized to the screen's free area: the window manager's title
    bar would push the bottom rows and the status bar off the screen.
    """
    screen = window.screen().availableGeometry() if window.screen() else None
    if screen is None:
        window.resize(width, height)
        return
    window.resize(min(width, screen.width()), min(height, screen.height()))
    if width > screen.width() or height + FRAME_PX > screen.height():
        window.setWindowState(window.windowState() | Qt.WindowState.WindowMaximized)
