"""Set OpenGL up in views the user has not seen yet.

A view's first render creates its OpenGL context state and compiles its shaders,
several times the cost of a later frame. The overlay tab is first shown by Accept
coarse, where that render would add to the stall of applying the result, so the
window shows each other tab for one frame of four dummy points when it opens.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    from PySide6.QtWidgets import QTabWidget

    from amrst_gui.views.scan_view import ScanView


def warm_up(view: ScanView) -> None:
    """Render once what a scene holds (coloured points, a caption), then drop
    it; only a visible view with no scene yet."""
    if view.closed or not view.isVisible() or view.scene is not None:
        return
    import pyvista as pv

    p = view.plotter
    dots = pv.PolyData(np.zeros((4, 3), np.float32))
    dots["rgb"] = np.zeros((4, 3), np.uint8)
    p.add_mesh(
        dots,
        scalars="rgb",
        rgb=True,
        style="points",
        point_size=2,
        name="_warm_up",
        reset_camera=False,
        render=False,
        pickable=False,
    )
    p.add_text("-", position="upper_left", font_size=9, name="_warm_up_text")
    p.render()
    p.remove_actor(["_warm_up", "_warm_up_text"], render=False)


def warm_up_tabs(tabs: QTabWidget, views: list[ScanView]) -> None:
    """Show each other tab of ``tabs`` holding any of ``views`` for one frame
    (:func:`warm_up`), then the current one again."""
    current = tabs.currentIndex()
    for i in range(tabs.count()):
        page = tabs.widget(i)
        inside = [v for v in views if page is not None and page.isAncestorOf(v)]
        if i == current or not inside:
            continue
        tabs.setCurrentIndex(i)
        for view in inside:
            warm_up(view)
    tabs.setCurrentIndex(current)
