"""The QtInteractor of the scan views: one render per frame, the wheel zooms to
the cursor."""

from __future__ import annotations

from pyvistaqt import QtInteractor

from amrst_gui.views.framing import zoom_towards

# One wheel notch (120 eighths of a degree) zooms by this factor.
WHEEL_ZOOM = 1.2


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

    def wheelEvent(self, ev) -> None:
        """Zoom toward the point under the cursor, not the view's centre (VTK's
        own wheel zoom), so a technician can close in on a feature to pick."""
        notches = ev.angleDelta().y() / 120.0
        if not notches or self.iren is None:
            return
        ratio = self.devicePixelRatioF()
        pos = ev.position()
        x = pos.x() * ratio
        y = (self.height() - pos.y() - 1) * ratio
        iren = self.iren.interactor
        # Start/End interaction: the view draws fewer points while it moves and
        # tells linked cameras when it stops, as for a drag.
        iren.InvokeEvent("StartInteractionEvent")
        zoom_towards(self.renderer, x, y, WHEEL_ZOOM**notches)
        iren.InvokeEvent("EndInteractionEvent")
        ev.accept()

    def close(self) -> None:
        """Close as pyvistaqt does, then let go of its GL context and surface.

        pyvistaqt keeps ``context().surface()`` until the context is destroyed. A
        surface is no QObject, so PySide cannot see it deleted, and a Qt object
        made later at its address (a table's selection model) came back as that
        stale QSurface wrapper. Nothing draws through them once closed.
        """
        super().close()
        self._forget_context()

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
