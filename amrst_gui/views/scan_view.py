"""ScanView: one QtInteractor that draws a Scene, and nothing else.

Level of detail (issue 15): each points layer has two actors, every displayed point
(at rest) and an even subset (``scene_jobs.MOVING_POINTS`` per view) shown only
while the camera moves; VTK's StartInteractionEvent / EndInteractionEvent switch
them. Multisampling is off: with software OpenGL it multiplied the cost of every
frame, and single-pixel points gain nothing from it.
"""

from __future__ import annotations

import numpy as np
import pyvista as pv
from PySide6.QtCore import Signal
from PySide6.QtWidgets import QVBoxLayout, QWidget
from pyvistaqt import QtInteractor

from amrst_gui.views.layers import (
    LinesLayer,
    PointsLayer,
    Scene,
    SpheresLayer,
    TextLayer,
)
from amrst_gui.views.picking import ClickPicker
from amrst_gui.views.scene_jobs import Prepared, prepare

BACKGROUND = (0.12, 0.13, 0.15)
_MOVING = "__moving"  # suffix of the actor drawn while the camera moves
_ELEVATION_DEG = 15
_VIEW_ANGLE_DEG = 30.0


def _lines_polydata(nodes: np.ndarray, edges: np.ndarray) -> pv.PolyData:
    edges = np.asarray(edges, dtype=np.int64).reshape(-1, 2)
    cells = np.hstack([np.full((len(edges), 1), 2, np.int64), edges]).ravel()
    return pv.PolyData(np.asarray(nodes, np.float32), lines=cells)


class _Interactor(QtInteractor):
    """A QtInteractor that draws each frame once.

    pyvistaqt renders in ``paintGL`` every time, also for the repaint that only
    shows a render just finished (``WindowFrameEvent``), so every frame cost two
    renders: 0.2-1 s each for 200,000 points with software OpenGL. Here that
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
        # auto_update=False: a closed window's timer froze the others (pyvistaqt#762).
        self.plotter = _Interactor(self, auto_update=False, multi_samples=0)
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
        self._moving_actors: dict[str, tuple] = {}  # name -> (still, moving) actors
        self._moving = False
        if self.plotter.iren is not None:
            self.plotter.iren.add_observer(
                "StartInteractionEvent", self._on_interaction_started
            )
            self.plotter.iren.add_observer(
                "EndInteractionEvent", self._on_interaction_ended
            )
        self.picker = ClickPicker(self.plotter, self.point_picked.emit)

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
    def moving(self) -> bool:
        """True while the user rotates, pans or zooms (fewer points drawn)."""
        return self._moving

    def drawn_points(self) -> int:
        """Points drawn now: the moving subset while the camera moves."""
        total = 0
        for name in self._keys:
            pair = self._moving_actors.get(name)
            if pair is None:
                continue
            actor = pair[1] if (self._moving and pair[1] is not None) else pair[0]
            total += actor.GetMapper().GetInput().GetNumberOfPoints()
        return total

    def update_scene(self, scene: Scene, prepared: Prepared | None = None) -> None:
        """Draw ``scene``: add changed layers, drop missing ones, then render once.

        ``prepared`` holds the VTK point sets made in a worker (scene_jobs); without
        it they are made here.
        """
        if self._closed or scene is self._scene:
            return
        if prepared is None:
            prepared = prepare(scene)
        wanted = scene.names()
        for name in [n for n in self._keys if n not in wanted]:
            self.plotter.remove_actor(name, render=False)
            self.plotter.remove_actor(name + _MOVING, render=False)
            self._moving_actors.pop(name, None)
            del self._keys[name]
        for layer in scene.layers:
            if self._keys.get(layer.name) == layer.key:
                continue
            self._draw(layer, prepared)
            self._keys[layer.name] = layer.key
        self._bounds = prepared.bounds
        self._scene = scene
        if scene.frame_key != self._frame_key:
            self._frame_key = scene.frame_key
            self.reset_camera(render=False)
        self.plotter.render()

    def reset_camera(
        self,
        render: bool = True,
        direction: tuple = (0.0, 1.0, 0.0),
        up: tuple = (0.0, 0.0, 1.0),
        elevation: float = _ELEVATION_DEG,
    ) -> None:
        """Look at the tree from the side (z up), the way it stands in the field;
        or along ``direction`` (from the camera to the tree) with ``up``.

        Set on the vtkCamera directly: pyvista's ``view_xz`` and ``reset_camera``
        recompute every actor's bounds and render, whatever ``render`` says (a
        second each on a 200,000-point view with software OpenGL).
        """
        if self._closed:
            return
        if not self.isVisible():  # a hidden tab has no real size yet: fit when shown
            self._fit_pending = True
            return
        self._fit_pending = False
        b = np.asarray(self._fit_bounds(), float)
        if not np.all(np.isfinite(b)):
            return
        cam = self.plotter.camera
        centre = (b[0::2] + b[1::2]) / 2
        cam.SetViewAngle(_VIEW_ANGLE_DEG)
        cam.SetFocalPoint(*centre)
        cam.SetPosition(*(centre - np.asarray(direction, float)))
        cam.SetViewUp(*up)
        if elevation:
            cam.Elevation(elevation)
            cam.OrthogonalizeViewUp()
        self.plotter.renderer.ResetCamera(*b)
        # ResetCamera fits the bounding sphere; a tree is tall and thin, so come
        # closer until its projected box fills the widget.
        corners = np.array(np.meshgrid(*b.reshape(3, 2))).reshape(3, -1).T - centre
        view_up = np.asarray(cam.GetViewUp())
        right = np.cross(np.asarray(cam.GetDirectionOfProjection()), view_up)
        need_w = np.ptp(corners @ right)
        need_h = np.ptp(corners @ view_up)
        span_h = 2 * cam.GetDistance() * np.tan(np.radians(_VIEW_ANGLE_DEG) / 2)
        aspect = max(self.plotter.width(), 1) / max(self.plotter.height(), 1)
        fit = 0.9 * min(span_h / max(need_h, 1e-9), span_h * aspect / max(need_w, 1e-9))
        if np.isfinite(fit) and fit > 1:
            cam.Dolly(fit)
        self.plotter.renderer.ResetCameraClippingRange(*b)
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
        """Aim at ``xyz`` (K, 3) from the current direction, filling the view.

        The camera looks at the centre of the points' box and comes as close as
        their extent across the screen (times ``margin``, at least ``2 *
        min_radius``) allows. A bounding sphere around the mean, as before, framed
        a tetrahedron with one vertex at the root and three in the crown from
        further away than the whole tree (issue 15).
        """
        if self._closed or len(xyz) == 0:
            return
        xyz = np.asarray(xyz, float)
        cam = self.plotter.camera
        centre = (xyz.min(axis=0) + xyz.max(axis=0)) / 2
        toward = np.asarray(cam.focal_point) - np.asarray(cam.position)
        toward /= max(np.linalg.norm(toward), 1e-12)
        up = np.asarray(cam.GetViewUp(), float)
        up -= toward * (up @ toward)
        up /= max(np.linalg.norm(up), 1e-12)
        right = np.cross(toward, up)
        rel = xyz - centre
        half_h = margin * max(np.ptp(rel @ up), 2 * min_radius) / 2
        half_w = margin * max(np.ptp(rel @ right), 2 * min_radius) / 2
        aspect = max(self.plotter.width(), 1) / max(self.plotter.height(), 1)
        tan_half = np.tan(np.radians(cam.GetViewAngle()) / 2)
        # Distance to the nearest of the points' depths, so no point is cut off
        # by perspective (nearer points look bigger).
        distance = max(half_h / tan_half, half_w / (tan_half * aspect))
        distance += float(np.max(-(rel @ toward), initial=0.0))
        cam.SetFocalPoint(*centre)
        cam.SetPosition(*(centre - toward * distance))
        cam.SetViewUp(*up)
        self.plotter.reset_camera_clipping_range()
        self.plotter.render()

    def showEvent(self, event) -> None:
        super().showEvent(event)
        if self._fit_pending and not self._closed:
            self.reset_camera()

    def close_view(self) -> None:
        """Close the plotter (before the widget goes; pyvistaqt#846)."""
        if not self._closed:
            self._closed = True
            self.plotter.close()

    def _draw(self, layer, prepared: Prepared) -> None:
        p = self.plotter
        if isinstance(layer, PointsLayer):
            still = self._add_points(prepared.still[layer.name], layer, layer.name)
            moving = prepared.moving.get(layer.name)
            if moving is not None:
                moving = self._add_points(moving, layer, layer.name + _MOVING)
                (still if self._moving else moving).SetVisibility(False)
            else:
                p.remove_actor(layer.name + _MOVING, render=False)
            self._moving_actors[layer.name] = (still, moving)
        elif isinstance(layer, LinesLayer):
            poly = _lines_polydata(layer.nodes, layer.edges)
            p.add_mesh(
                poly,
                color=layer.color,
                line_width=layer.width,
                name=layer.name,
                reset_camera=False,
                render=False,
                pickable=False,
            )
        elif isinstance(layer, SpheresLayer):
            centers = pv.PolyData(np.asarray(layer.centers, np.float32))
            centers["rgb"] = layer.rgb
            sphere = pv.Sphere(
                radius=layer.radius, theta_resolution=12, phi_resolution=8
            )
            glyphs = centers.glyph(geom=sphere, scale=False, orient=False)
            p.add_mesh(
                glyphs,
                scalars="rgb",
                rgb=True,
                name=layer.name,
                reset_camera=False,
                render=False,
                pickable=False,
            )
        elif isinstance(layer, TextLayer):
            p.add_text(
                layer.text,
                position=layer.position,
                font_size=9,
                color="white",
                name=layer.name,
                render=False,
            )

    def _add_points(self, poly, layer: PointsLayer, name: str):
        return self.plotter.add_mesh(
            poly,
            scalars="rgb",
            rgb=True,
            style="points",
            point_size=layer.point_size,
            name=name,
            reset_camera=False,
            render=False,
            pickable=False,
        )

    def _show_moving(self, moving: bool) -> None:
        self._moving = moving
        for still, subset in self._moving_actors.values():
            if subset is not None:
                still.SetVisibility(not moving)
                subset.SetVisibility(moving)

    def _on_interaction_started(self, *_args) -> None:
        self._show_moving(True)

    def _on_interaction_ended(self, *_args) -> None:
        if self._moving:
            self._show_moving(False)
            if not self._closed:
                self.plotter.render()  # full detail at rest
        self.camera_moved.emit()
