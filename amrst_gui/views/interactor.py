"""The QtInteractor of the scan views: one render per frame."""

from __future__ import annotations

from pyvistaqt import QtInteractor


class Interactor(QtInteractor):
    """A QtInteractor that draws each frame once.

    pyvistaqt renders in ``paintGL`` every time, also for the repaint that only
    shows a render just finished (``WindowFrameEvent``), so every frame cost two
    renders. Here that
    repaint only copies the finished frame to the widget, as VTK's own C++ widget
    does. Other repaints (expose, resize, grab) still render: pyvistaqt renders
    there because pyvista may change a scene without rendering; ScanView renders
    after every change it makes.
    """

    _fresh_frame = False
    _in_paint: bool  # pyvistaqt's (set in its __init__)

    def _cb_frame(self, obj, evt) -> None:
        if not self._in_paint:
            self._fresh_frame = True
        super()._cb_frame(obj, evt)

    def render_offscreen(self) -> None:
        """Render into the widget's framebuffer while it is hidden (its point
        sets uploaded before it is shown); the paint that shows it renders again,
        never this picture, whose camera may not be fitted yet."""
        self.grabFramebuffer()
        self._fresh_frame = False

    def resizeGL(self, w: int, h: int) -> None:
        self._fresh_frame = False
        super().resizeGL(w, h)

    def paintGL(self) -> None:
        if not (self._fresh_frame and not self._in_paint):
            self._fresh_frame = False
            super().paintGL()
            return
        self._fresh_frame = False
        self._in_paint = True  # makes pyvistaqt's paintGL blit without rendering
        try:
            super().paintGL()
        finally:
            self._in_paint = False
