"""Linked cameras for the target and source views.

The scans are in different frames, so sharing one vtkCamera would point the
source view at empty space. Instead the camera is copied relative to each
scene's centre, turned by the best transform known so far (coarse or fine):
a direction ``d`` in the target frame is ``R.T @ d`` in the source frame.
"""

from __future__ import annotations

import numpy as np
from PySide6.QtCore import QObject


class CameraLink(QObject):
    """Keeps two ScanViews looking at their trees from the same side.

    Listens to the views' ``camera_moved``; reads ``session.final_transform``
    or ``session.coarse``; emits nothing.
    """

    def __init__(self, session, target_view, source_view) -> None:
        super().__init__(target_view)
        self.session = session
        self.views = {"target": target_view, "source": source_view}
        self.enabled = False
        self._syncing = False
        target_view.camera_moved.connect(lambda: self._on_camera_moved("target"))
        source_view.camera_moved.connect(lambda: self._on_camera_moved("source"))

    def set_enabled(self, on: bool) -> None:
        """Link or unlink; linking aligns the source view to the target view."""
        self.enabled = bool(on)
        if self.enabled:
            self._on_camera_moved("target")

    def _rotation_target_source(self) -> np.ndarray:
        T = self.session.final_transform
        if T is None and self.session.coarse is not None:
            T = self.session.coarse.T_target_source
        return np.eye(3) if T is None else np.asarray(T)[:3, :3]

    def _on_camera_moved(self, role: str) -> None:
        if not self.enabled or self._syncing:
            return
        src, dst = (
            self.views[role],
            self.views["source" if role == "target" else "target"],
        )
        if src.scene is None or dst.scene is None:
            return
        R = self._rotation_target_source()
        # Direction from the moving view's frame into the other view's frame.
        R_dst_src = R.T if role == "target" else R
        cam, other = src.plotter.camera, dst.plotter.camera
        offset = np.asarray(cam.position) - np.asarray(cam.focal_point)
        focal_shift = np.asarray(cam.focal_point) - src.scene.center
        self._syncing = True
        try:
            center = dst.scene.center
            other.focal_point = tuple(center + R_dst_src @ focal_shift)
            other.position = tuple(
                center + R_dst_src @ focal_shift + R_dst_src @ offset
            )
            other.up = tuple(R_dst_src @ np.asarray(cam.up))
            other.view_angle = cam.view_angle
            dst.plotter.reset_camera_clipping_range()
            dst.plotter.render()
        finally:
            self._syncing = False
