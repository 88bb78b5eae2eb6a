"""Pick a point in a scan view as a user does: zoom onto it, then click it."""

from __future__ import annotations

import numpy as np


def click(view, xyz) -> None:
    """Zoom onto ``xyz``, then click (press, release) where it is drawn, through
    VTK's own events."""
    view.frame_points(np.asarray([xyz]), min_radius=0.5)
    ren = view.plotter.renderer
    ren.SetWorldPoint(*xyz, 1.0)
    ren.WorldToDisplay()
    x, y, _ = ren.GetDisplayPoint()
    iren = view.plotter.iren.interactor
    iren.SetEventInformation(round(x), round(y))
    iren.InvokeEvent("LeftButtonPressEvent")
    iren.InvokeEvent("LeftButtonReleaseEvent")
