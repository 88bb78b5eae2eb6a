"""Marks of the point pairs in a scan view: numbered markers, the other scan.

Each picked point is a round marker with its pair's number beside it; a point
waiting for its partner is drawn in another colour. Under a rough pose the other
scan can be drawn faintly in the same view (a ghost), so the same side of a trunk is
found by eye. The actors live apart from the view's Scene (they change at each
click, the scene does not). Made and changed on the GUI thread only.
"""

from __future__ import annotations

import numpy as np

# Red markers and a white ghost: colours neither the height map (viridis: purple to
# yellow) nor the overlay (amber, blue) nor wood / leaf (brown, green) uses.
PAIR_RGB = (1.0, 0.1, 0.1)
PENDING_RGB = (1.0, 1.0, 0.2)
GHOST_RGB = (0.95, 0.95, 0.95)
# pyvista names the labels' actor after the name given, plus "-labels".
LABELS_ACTOR = "pick_labels-labels"
_NAMES = ("pick_markers", "pick_pending", LABELS_ACTOR, "pick_ghost")


class PickMarks:
    """The pair markers and the ghost of one view's plotter."""

    def __init__(self, plotter) -> None:
        self.plotter = plotter
        self.points = np.zeros((0, 3))
        self.labels: list[str] = []
        self.pending: np.ndarray | None = None
        self.ghost_points = 0

    def set_markers(
        self,
        xyz: np.ndarray,
        labels: list[str],
        pending: np.ndarray | None = None,
    ) -> None:
        """Mark ``xyz`` (K, 3) with ``labels``; ``pending`` (3,): a point waiting
        for its pair, in its own colour."""
        p = self.plotter
        points = np.asarray(xyz, float).reshape(-1, 3)
        had = len(self.points) or self.pending is not None
        if not had and not len(points) and pending is None:
            return  # none before, none now: no render for nothing
        self.points = points
        self.labels = list(labels)
        self.pending = None if pending is None else np.asarray(pending, float)
        for name in _NAMES[:3]:
            p.remove_actor(name, render=False)
        if len(self.points):
            p.add_points(
                self.points.astype(np.float32),
                color=PAIR_RGB,
                point_size=16,
                render_points_as_spheres=True,
                ambient=0.5,  # lit from any side: shading would darken the red
                name="pick_markers",
                pickable=False,
                reset_camera=False,
                render=False,
            )
        if self.pending is not None:
            p.add_points(
                self.pending.reshape(1, 3).astype(np.float32),
                color=PENDING_RGB,
                point_size=16,
                render_points_as_spheres=True,
                name="pick_pending",
                pickable=False,
                reset_camera=False,
                render=False,
            )
        shown = [*self.points] + ([] if self.pending is None else [self.pending])
        if shown:
            p.add_point_labels(
                np.asarray(shown, np.float32),
                self.labels + ([] if self.pending is None else ["?"]),
                font_size=16,
                text_color="white",
                shape_color=(0.25, 0.1, 0.25),
                shape_opacity=0.6,
                show_points=False,
                always_visible=True,
                name="pick_labels",
                pickable=False,
                reset_camera=False,
                render=False,
            )
        p.render()

    def set_ghost(self, xyz: np.ndarray | None) -> None:
        """Draw the other scan's points ``xyz`` (N, 3, this view's frame) faintly,
        or drop them (None)."""
        p = self.plotter
        if not self.ghost_points and (xyz is None or not len(xyz)):
            return  # none before, none now
        p.remove_actor("pick_ghost", render=False)
        self.ghost_points = 0 if xyz is None else len(xyz)
        if xyz is not None and len(xyz):
            p.add_points(
                np.asarray(xyz, np.float32),
                color=GHOST_RGB,
                point_size=2,
                opacity=0.35,
                name="pick_ghost",
                pickable=False,
                reset_camera=False,
                render=False,
            )
        p.render()

    def clear(self) -> None:
        """Drop every mark."""
        for name in _NAMES:
            self.plotter.remove_actor(name, render=False)
        self.points, self.labels, self.pending = np.zeros((0, 3)), [], None
        self.ghost_points = 0
