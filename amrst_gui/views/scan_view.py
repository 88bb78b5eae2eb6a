"""ScanView: one QtInteractor that draws a Scene, and nothing else."""

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

BACKGROUND = (0.12, 0.13, 0.15)
_ELEVATION_DEG = 15


def _lines_polydata(nodes: np.ndarray, edges: np.ndarray) -> pv.PolyData:
    edges = np.asarray(edges, dtype=np.int64).reshape(-1, 2)
    cells = np.hstack([np.full((len(edges), 1), 2, np.int64), edges]).ravel()
    return pv.PolyData(np.asarray(nodes, np.float32), lines=cells)


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
        self.plotter = QtInteractor(self, auto_update=False)
        # QtInteractor would add a dropped file to its scene; the pane handles drops.
        self.plotter.setAcceptDrops(False)
        self.plotter.set_background(BACKGROUND)
        layout.addWidget(self.plotter)
        self._keys: dict[str, tuple] = {}
        self._frame_key: tuple | None = None
        self._scene: Scene | None = None
        self._closed = False
        self._fit_pending = False
        if self.plotter.iren is not None:
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

    def update_scene(self, scene: Scene) -> None:
        """Draw ``scene``: add changed layers, drop missing ones, then render once."""
        if self._closed or scene is self._scene:
            return
        wanted = scene.names()
        for name in [n for n in self._keys if n not in wanted]:
            self.plotter.remove_actor(name, render=False)
            del self._keys[name]
        for layer in scene.layers:
            if self._keys.get(layer.name) == layer.key:
                continue
            self._draw(layer)
            self._keys[layer.name] = layer.key
        self._scene = scene
        if scene.frame_key != self._frame_key:
            self._frame_key = scene.frame_key
            self.reset_camera(render=False)
        self.plotter.render()

    def reset_camera(self, render: bool = True) -> None:
        """Look at the tree from the side (z up), the way it stands in the field."""
        if self._closed:
            return
        if not self.isVisible():  # a hidden tab has no real size yet: fit when shown
            self._fit_pending = True
            return
        self._fit_pending = False
        p = self.plotter
        p.view_xz(render=False)
        p.camera.elevation = _ELEVATION_DEG
        b = self._fit_bounds()
        p.reset_camera(render=False, bounds=b)
        # reset_camera fits the bounding sphere; a tree is tall and thin, so zoom in
        # until its side view fills the widget.
        ext = b[1::2] - b[0::2]
        if np.all(np.isfinite(ext)) and ext.max() > 0:
            elev = np.radians(_ELEVATION_DEG)
            need_h = ext[2] * np.cos(elev) + ext[1] * np.sin(elev)
            need_w = ext[0]
            cam = p.camera
            span_h = 2 * cam.distance * np.tan(np.radians(cam.view_angle) / 2)
            aspect = max(self.plotter.width(), 1) / max(self.plotter.height(), 1)
            fit = 0.9 * min(
                span_h / max(need_h, 1e-9), span_h * aspect / max(need_w, 1e-9)
            )
            if fit > 1:
                cam.zoom(fit)
        if render:
            p.render()

    def _fit_bounds(self) -> np.ndarray:
        """Bounds to frame: the points' 0.5-99.5 percentiles, plus 5 % each side.

        A few stray points metres away (real scans have them) would otherwise push
        the tree into a corner of the view.
        """
        layers = [] if self._scene is None else self._scene.layers
        pts = [ly.xyz for ly in layers if isinstance(ly, PointsLayer) and len(ly.xyz)]
        if not pts:
            return np.asarray(self.plotter.bounds, dtype=float)
        xyz = np.concatenate(pts)
        lo, hi = np.percentile(xyz, [0.5, 99.5], axis=0)
        pad = 0.05 * (hi - lo)
        return np.column_stack([lo - pad, hi + pad]).ravel()

    def frame_points(
        self, xyz: np.ndarray, margin: float = 1.3, min_radius: float = 0.05
    ) -> None:
        """Aim at ``xyz`` (K, 3) from the current direction, filling the view."""
        if self._closed or len(xyz) == 0:
            return
        cam = self.plotter.camera
        center = np.asarray(xyz, float).mean(axis=0)
        spread = float(np.linalg.norm(xyz - center, axis=1).max())
        radius = max(spread * margin, min_radius)
        direction = np.asarray(cam.position) - np.asarray(cam.focal_point)
        direction /= max(np.linalg.norm(direction), 1e-12)
        distance = radius / np.tan(np.radians(cam.view_angle) / 2)
        cam.focal_point = tuple(center)
        cam.position = tuple(center + direction * distance)
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

    def _draw(self, layer) -> None:
        p = self.plotter
        if isinstance(layer, PointsLayer):
            poly = pv.PolyData(np.asarray(layer.xyz, np.float32))
            poly["rgb"] = layer.rgb
            p.add_mesh(
                poly,
                scalars="rgb",
                rgb=True,
                style="points",
                point_size=layer.point_size,
                name=layer.name,
                reset_camera=False,
                render=False,
                pickable=False,
            )
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

    def _on_interaction_ended(self, *_args) -> None:
        self.camera_moved.emit()
