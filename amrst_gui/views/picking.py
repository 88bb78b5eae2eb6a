"""Point picking in a ScanView: a click snaps to the nearest point of the cloud.

The projection is VTK's own camera matrix, applied to the points in numpy, so a click
snaps to the point drawn nearest to the cursor (the front one when several are), not
to whatever surface a ray happens to hit. No Qt here beyond what the view passes in.
"""

from __future__ import annotations

import numpy as np

SNAP_PX = 12.0  # a click farther than this from every point picks nothing
_CLICK_PX = 4  # a press and release farther apart than this is a drag, not a click


def project(renderer, xyz: np.ndarray) -> np.ndarray:
    """(N, 3) display coordinates (x, y in pixels, origin bottom-left; z depth)."""
    cam = renderer.GetActiveCamera()
    aspect = renderer.GetTiledAspectRatio()
    m = cam.GetCompositeProjectionTransformMatrix(aspect, -1, 1)
    M = np.array([[m.GetElement(i, j) for j in range(4)] for i in range(4)])
    h = np.c_[np.asarray(xyz, float), np.ones(len(xyz))] @ M.T
    ndc = h[:, :3] / h[:, 3:4]
    w, ht = renderer.GetSize()
    ox, oy = renderer.GetOrigin()
    return np.c_[(ndc[:, 0] + 1) / 2 * w + ox, (ndc[:, 1] + 1) / 2 * ht + oy, ndc[:, 2]]


def snap(renderer, xyz: np.ndarray, x: float, y: float) -> int | None:
    """Index of the point of ``xyz`` drawn nearest to display (x, y), or None.

    Among points within a pixel of the nearest one, the one in front wins.
    """
    if len(xyz) == 0:
        return None
    p = project(renderer, xyz)
    d = np.hypot(p[:, 0] - x, p[:, 1] - y)
    visible = (p[:, 2] > -1) & (p[:, 2] < 1)
    d[~visible] = np.inf
    best = float(d.min())
    if not np.isfinite(best) or best > SNAP_PX:
        return None
    near = np.flatnonzero(d <= best + 1.0)
    return int(near[np.argmin(p[near, 2])])


class ClickPicker:
    """Turns a left click (not a drag) on a view's interactor into a picked point.

    ``points`` is the (N, 3) cloud clicks snap to; ``on_pick(index, xyz)`` is called
    for each pick while ``enabled``.
    """

    def __init__(self, plotter, on_pick) -> None:
        self.plotter = plotter
        self.on_pick = on_pick
        self.points = np.zeros((0, 3))
        self.enabled = False
        self._press: tuple[int, int] | None = None
        iren = plotter.iren
        if iren is not None:
            iren.add_observer("LeftButtonPressEvent", self._on_press)
            iren.add_observer("LeftButtonReleaseEvent", self._on_release)

    def _position(self) -> tuple[int, int]:
        x, y = self.plotter.iren.interactor.GetEventPosition()
        return int(x), int(y)

    def _on_press(self, *_args) -> None:
        self._press = self._position() if self.enabled else None

    def _on_release(self, *_args) -> None:
        if not self.enabled or self._press is None:
            return
        x, y = self._position()
        px, py = self._press
        self._press = None
        if abs(x - px) > _CLICK_PX or abs(y - py) > _CLICK_PX:
            return  # the user turned the view
        self.click(x, y)

    def click(self, x: float, y: float) -> int | None:
        """Snap display (x, y) to a point and report it; returns its index."""
        i = snap(self.plotter.renderer, self.points, x, y)
        if i is not None:
            self.on_pick(i, np.asarray(self.points[i], float))
        return i
