"""ScanView: one QtInteractor that draws a Scene, and nothing else.

Every VTK object of a view is made, changed and dropped here, on the GUI thread,
from the arrays of a Scene and its Prepared levels. Level of detail: every frame is timed (``lod.COST``); at rest a view
draws the largest level of detail (all displayed points, or every 2nd, 4th, ...)
whose frame fits ``lod.REST_BUDGET_S``, going up one level per frame after a new
scene, and while the camera moves (VTK's StartInteractionEvent /
EndInteractionEvent) the largest up to ``scene.MOVING_POINTS`` that fits
``lod.MOVING_BUDGET_S``; the caption says how many points are drawn at rest.
Multisampling is off: with software OpenGL it multiplied the cost of every
frame, and single-pixel points gain nothing from it.
"""

from __future__ import annotations

import time

import numpy as np
from PySide6.QtCore import Signal
from PySide6.QtWidgets import QVBoxLayout, QWidget

from amrst_gui.pacing import DRAWS
from amrst_gui.views import framing, lod
from amrst_gui.views.detail import PointLevels, with_shown
from amrst_gui.views.interactor import Interactor
from amrst_gui.views.layers import (
    LinesLayer,
    PointsLayer,
    Scene,
    SpheresLayer,
    TextLayer,
)
from amrst_gui.views.pick_marks import PickMarks
from amrst_gui.views.picking import ClickPicker
from amrst_gui.views.scene import MOVING_POINTS
from amrst_gui.views.scene_jobs import Prepared, prepare

BACKGROUND = (0.12, 0.13, 0.15)
_ELEVATION_DEG = 15


class ScanView(QWidget):
    """A 3D view: ``update_scene(scene)`` makes its actors match the scene.

    Listens to no session signal (its pane calls ``update_scene``); emits
    ``camera_moved()`` when the user ends a rotate/pan/zoom, for linked cameras.
    Every actor is named after its layer, so an update replaces, never piles up.
    """

    camera_moved = Signal()
    point_picked = Signal(int, object)  # index into pick_points, (3,) xyz

    def __init__(self, parent: QWidget | None = None) -> None:
        super().__init__(parent)
        layout = QVBoxLayout(self)
        layout.setContentsMargins(0, 0, 0, 0)
        # auto_update=False: pyvistaqt's update timer of a closed window froze the others.
        self.plotter = Interactor(self, auto_update=False, multi_samples=0)
        self.plotter.disable_anti_aliasing()
        # QtInteractor would add a dropped file to its scene; the pane handles drops.
        self.plotter.setAcceptDrops(False)
        self.plotter.set_background(BACKGROUND)
        layout.addWidget(self.plotter)
        self._keys: dict[str, tuple] = {}
        self._frame_key: tuple | None = None
        self._scene: Scene | None = None
        self._closed = False
        self._fit_pending = False
        self._bounds: np.ndarray | None = None
        self._points = PointLevels(self.plotter)
        self._rest_level: int | None = None  # None: no points drawn yet
        self._moving = False
        self._frame_start = 0.0
        self._frames = 0
        self._caption: str | None = None  # the title as drawn
        self._shown_once = False  # OpenGL set up (shown at least once)
        self._prerendered: Scene | None = None
        rw = self.plotter.ren_win
        if rw is not None:
            rw.AddObserver("StartEvent", self._on_frame_start)
            rw.AddObserver("EndEvent", self._on_frame_end)
        if self.plotter.iren is not None:
            self.plotter.iren.add_observer(
                "StartInteractionEvent", self._on_interaction_started
            )
            self.plotter.iren.add_observer(
                "EndInteractionEvent", self._on_interaction_ended
            )
        self.picker = ClickPicker(self.plotter, self.point_picked.emit)
        self.marks = PickMarks(self.plotter)  # point pairs' markers, a ghost

    def set_picking(self, on: bool, points: np.ndarray | None = None) -> None:
        """Let a left click pick (snap to) one of ``points`` (N, 3); emits
        ``point_picked(index, xyz)``."""
        self.picker.enabled = on
        if points is not None:
            self.picker.points = np.asarray(points)

    @property
    def scene(self) -> Scene | None:
        """The scene drawn last."""
        return self._scene

    def actor_names(self) -> set[str]:
        """Names of the layers currently drawn."""
        return set(self._keys)

    @property
    def closed(self) -> bool:
        """True once ``close_view`` was called."""
        return self._closed

    @property
    def moving(self) -> bool:
        """True while the user rotates, pans or zooms (fewer points drawn)."""
        return self._moving

    def drawn_points(self) -> int:
        """Points drawn now: fewer while the camera moves, or when a frame of all
        would take too long (``lod``)."""
        return self._points.drawn()

    def caption(self) -> str | None:
        """The title as drawn (its "showing N of M points" says ``drawn_points``
        at rest)."""
        return self._caption

    def update_scene(self, scene: Scene, prepared: Prepared | None = None) -> None:
        """Draw ``scene``: add changed layers, drop missing ones, then render once.

        ``prepared`` holds the point layers' levels cut in a worker (scene_jobs);
        without it they are cut here.
        """
        if self._closed or scene is self._scene:
            return
        self._update_scene(scene, prepared)
        self.plotter.render()

    def _update_scene(self, scene: Scene, prepared: Prepared | None) -> None:
        if prepared is None:
            prepared = prepare(scene)
        wanted = scene.names()
        for name in [n for n in self._keys if n not in wanted]:
            self.plotter.remove_actor(name, render=False)
            self._points.remove(name)
            del self._keys[name]
        # New point sets (a first scene, a moved or recoloured scan) start low
        # (lod.pick) and step up a level per frame: their first frame uploads
        # them too, which at the rest level would stall the window.
        if not self._points.names() or any(
            isinstance(layer, PointsLayer) and self._keys.get(layer.name) != layer.key
            for layer in scene.layers
        ):
            self._rest_level = None
        for layer in scene.layers:
            if self._keys.get(layer.name) == layer.key:
                continue
            self._draw(layer, prepared)
            self._keys[layer.name] = layer.key
        self._bounds = prepared.bounds
        self._scene = scene
        self._choose_level(self._rest_level is None)
        self._sync_caption()
        if scene.frame_key != self._frame_key:
            self._frame_key = scene.frame_key
            self.reset_camera(render=False)

    def prerender(self) -> None:
        """Draw a hidden view's points once, off screen (its pane calls this
        while no step runs): the first frame of point sets a view never drew
        costs more than the next ones, and the overlay's would come with Accept
        coarse, in one stall with its panels."""
        if self._closed or self.isVisible() or not self._shown_once:
            return
        if not self._points.names() or self._prerendered is self._scene:
            return
        self._prerendered = self._scene
        self._choose_level(True)
        self.plotter.render_offscreen()
        DRAWS.mark()

    def reset_camera(
        self,
        render: bool = True,
        direction: tuple = (0.0, 1.0, 0.0),
        up: tuple = (0.0, 0.0, 1.0),
        elevation: float = _ELEVATION_DEG,
    ) -> None:
        """Look at the tree from the side (z up), the way it stands in the field;
        or along ``direction`` (from the camera to the tree) with ``up``
        (``framing.side_view``)."""
        if self._closed:
            return
        if not self.isVisible():  # a hidden tab has no real size yet: fit when shown
            self._fit_pending = True
            return
        self._fit_pending = False
        b = np.asarray(self._fit_bounds(), float)
        if not np.all(np.isfinite(b)):
            return
        # Not ``plotter.camera``: the first time, pyvista fits the camera itself
        # and renders, three renders in all.
        aspect = max(self.plotter.width(), 1) / max(self.plotter.height(), 1)
        framing.side_view(self.plotter.renderer, b, aspect, direction, up, elevation)
        self.plotter.renderer.camera_set = True  # pyvista: do not fit it again
        if render:
            self.plotter.render()

    def _fit_bounds(self) -> np.ndarray:
        """Bounds to frame: the points' 0.5-99.5 percentiles plus 5 % each side,
        computed with the scene (``scene_jobs.fit_bounds``, in the worker)."""
        if self._bounds is None:
            return np.asarray(self.plotter.bounds, dtype=float)
        return self._bounds

    def frame_points(
        self, xyz: np.ndarray, margin: float = 1.2, min_radius: float = 0.05
    ) -> None:
        """Aim at ``xyz`` (K, 3) from the current direction, filling the view
        (``framing.aim_at``)."""
        if self._closed or len(xyz) == 0:
            return
        aspect = max(self.plotter.width(), 1) / max(self.plotter.height(), 1)
        framing.aim_at(
            self.plotter.camera, np.asarray(xyz, float), aspect, margin, min_radius
        )
        self.plotter.reset_camera_clipping_range()
        self.plotter.render()

    def showEvent(self, event) -> None:
        super().showEvent(event)
        if self._closed:
            return
        self._shown_once = True
        # A view coming into sight (its tab chosen; the overlay after Accept
        # coarse) starts at a low level of detail and steps up a level per frame,
        # like a new scene: its first frame at the rest level would stall.
        if self._rest_level is not None:
            self._choose_level(True)
            self._sync_caption()
        if self._fit_pending:
            # The paint that shows the widget renders: one frame, not two.
            self.reset_camera(render=False)
        self.plotter.update()

    def close_view(self) -> None:
        """Close the plotter before the widget goes (else VTK draws into a dead window)."""
        if not self._closed:
            self._closed = True
            self.plotter.close()

    def _draw(self, layer, prepared: Prepared) -> None:
        p = self.plotter
        if isinstance(layer, PointsLayer):
            self._points.set_layer(
                layer.name, prepared.sets[layer.name], layer.point_size
            )
        elif isinstance(layer, LinesLayer):
            p.add_mesh(
                lines_mesh(layer),
                color=layer.color,
                line_width=layer.width,
                name=layer.name,
                reset_camera=False,
                render=False,
                pickable=False,
            )
        elif isinstance(layer, SpheresLayer):
            p.add_mesh(
                spheres_mesh(layer),
                scalars="rgb",
                rgb=True,
                name=layer.name,
                reset_camera=False,
                render=False,
                pickable=False,
            )
        elif isinstance(layer, TextLayer):
            if layer.name == "title":
                return  # _sync_caption draws it
            p.add_text(
                layer.text,
                position=layer.position,
                font_size=9,
                color="white",
                name=layer.name,
                render=False,
            )

    # ----------------------------------------------------------- level of detail
    def _choose_level(self, first: bool) -> None:
        """Show the rest level ``lod.pick`` gives (the moving one while moving)."""
        levels = self._points.levels()
        if not levels:
            self._rest_level = None
            return
        drawn = None if first else levels[min(self._rest_level or 0, len(levels) - 1)]
        self._rest_level = lod.pick(levels, lod.REST_BUDGET_S, drawn)
        self._points.show(self._moving_level() if self._moving else self._rest_level)

    def _moving_level(self) -> int:
        levels = self._points.levels()
        return lod.pick(levels, lod.MOVING_BUDGET_S, None, cap=MOVING_POINTS)

    def _sync_caption(self) -> None:
        """Draw the title with "showing N of M points" as drawn at rest."""
        layers = () if self._scene is None else self._scene.layers
        title = next(
            (ly for ly in layers if isinstance(ly, TextLayer) and ly.name == "title"),
            None,
        )
        if title is None:
            self._caption = None
            return
        if not self._moving and self._points.names():
            text = with_shown(title.text, self._points.drawn())
        else:
            text = self._caption or title.text
        if text == self._caption:
            return
        actor = self.plotter.actors.get(title.name)
        if self._caption is not None and hasattr(actor, "set_text"):
            actor.set_text(title.position, text)  # in place: add_text is slow
        else:
            self.plotter.add_text(
                text,
                position=title.position,
                font_size=9,
                color="white",
                name=title.name,
                render=False,
            )
        self._caption = text

    def _on_frame_start(self, *_args) -> None:
        self._frame_start = time.perf_counter()

    def _on_frame_end(self, *_args) -> None:
        DRAWS.mark()
        seconds = time.perf_counter() - self._frame_start
        drawn = self._points.drawn()
        if drawn:
            self._frames += 1
            if self._frames > 1:  # the first frame of points also sets OpenGL up
                lod.COST.record(drawn, seconds)
        if not (self._moving or self._closed):
            DRAWS.later(self, "adapt", self._adapt)

    def _adapt(self) -> None:
        """After a frame at rest: go up a level while it fits the budget, down
        when it did not fit; then draw again."""
        if self._closed or self._moving or self._rest_level is None:
            return
        before = self._rest_level
        self._choose_level(False)
        if self._rest_level != before:
            self._sync_caption()
            self.plotter.render()

    def _show_moving(self, moving: bool) -> None:
        self._moving = moving
        if self._rest_level is not None:
            self._points.show(self._moving_level() if moving else self._rest_level)

    def _on_interaction_started(self, *_args) -> None:
        self._show_moving(True)

    def _on_interaction_ended(self, *_args) -> None:
        if self._moving:
            self._show_moving(False)
            if not self._closed:
                self.plotter.render()  # full detail at rest
        self.camera_moved.emit()


def lines_mesh(layer: LinesLayer):
    """The skeleton's edges as VTK lines."""
    import pyvista as pv

    edges = np.asarray(layer.edges, dtype=np.int64).reshape(-1, 2)
    cells = np.hstack([np.full((len(edges), 1), 2, np.int64), edges]).ravel()
    return pv.PolyData(np.asarray(layer.nodes, np.float32), lines=cells)


def spheres_mesh(layer: SpheresLayer):
    """One small sphere per centre, coloured by ``layer.rgb``."""
    import pyvista as pv

    centers = pv.PolyData(np.asarray(layer.centers, np.float32))
    centers["rgb"] = layer.rgb
    sphere = pv.Sphere(radius=layer.radius, theta_resolution=12, phi_resolution=8)
    return centers.glyph(geom=sphere, scale=False, orient=False)
