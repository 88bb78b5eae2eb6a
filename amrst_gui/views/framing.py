"""Where a view's camera looks (no Qt): the side view of a tree, and aiming at
points. Set on the vtkCamera directly: pyvista's ``view_xz`` and
``reset_camera`` recompute every actor's bounds and render, which is slow on a
big view."""

from __future__ import annotations

import numpy as np

VIEW_ANGLE_DEG = 30.0
#: The Top, Front and Side views: from the camera to the tree, and the screen's up.
LOOKS = {
    "Top": ((0.0, 0.0, -1.0), (0.0, 1.0, 0.0)),
    "Front": ((0.0, 1.0, 0.0), (0.0, 0.0, 1.0)),
    "Side": ((-1.0, 0.0, 0.0), (0.0, 0.0, 1.0)),
}


def side_view(
    renderer, b: np.ndarray, aspect: float, direction, up, elevation: float
) -> None:
    """Look at the box ``b`` (xmin, xmax, ymin, ymax, zmin, zmax) along
    ``direction`` with ``up``, raised by ``elevation`` degrees, as close as its
    projected box still fits a widget of ``aspect`` (width / height)."""
    cam = renderer.GetActiveCamera()
    centre = (b[0::2] + b[1::2]) / 2
    cam.SetViewAngle(VIEW_ANGLE_DEG)
    cam.SetFocalPoint(*centre)
    cam.SetPosition(*(centre - np.asarray(direction, float)))
    cam.SetViewUp(*up)
    if elevation:
        cam.Elevation(elevation)
        cam.OrthogonalizeViewUp()
    renderer.ResetCamera(*b)
    # ResetCamera fits the bounding sphere; a tree is tall and thin, so come
    # closer until its box fills the widget. Each corner must fit at its own
    # depth: seen from above, the crown is nearer the camera than the stem foot.
    corners = np.array(np.meshgrid(*b.reshape(3, 2))).reshape(3, -1).T - centre
    view_up = np.asarray(cam.GetViewUp())
    toward = np.asarray(cam.GetDirectionOfProjection())
    right = np.cross(toward, view_up)
    half = 0.9 * np.tan(np.radians(VIEW_ANGLE_DEG) / 2)  # of the span per metre
    across = np.maximum(np.abs(corners @ view_up), np.abs(corners @ right) / aspect)
    distance = float(np.max(across / half - corners @ toward))
    if np.isfinite(distance) and 0 < distance < cam.GetDistance():
        cam.SetPosition(*(centre - toward * distance))
    renderer.ResetCameraClippingRange(*b)


def aim_at(
    cam, xyz: np.ndarray, aspect: float, margin: float, min_radius: float
) -> None:
    """Aim ``cam`` at ``xyz`` (K, 3) from its current direction, as close as
    their extent across the screen (times ``margin``, at least ``2 *
    min_radius``) allows. The camera looks at the centre of the points' box: a
    bounding sphere around their mean framed a tetrahedron with one vertex at
    the root and three in the crown from further away than the whole tree."""
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
    tan_half = np.tan(np.radians(cam.GetViewAngle()) / 2)
    # Distance to the nearest of the points' depths, so no point is cut off
    # by perspective (nearer points look bigger).
    distance = max(half_h / tan_half, half_w / (tan_half * aspect))
    distance += float(np.max(-(rel @ toward), initial=0.0))
    cam.SetFocalPoint(*centre)
    cam.SetPosition(*(centre - toward * distance))
    cam.SetViewUp(*up)


def zoom_towards(renderer, x: float, y: float, factor: float) -> None:
    """Zoom by ``factor`` (> 1 closer) keeping what lies under display (x, y) there.

    The camera and its focal point move together toward the point of the focal
    plane under the cursor, so what the user points at stays under the pointer.
    """
    cam = renderer.GetActiveCamera()
    fp = np.array(cam.GetFocalPoint(), float)
    renderer.SetWorldPoint(*fp, 1.0)
    renderer.WorldToDisplay()
    depth = renderer.GetDisplayPoint()[2]
    renderer.SetDisplayPoint(float(x), float(y), depth)
    renderer.DisplayToWorld()
    w = np.array(renderer.GetWorldPoint(), float)
    if w[3] == 0:
        return
    target = w[:3] / w[3]
    step = 1.0 - 1.0 / factor
    if cam.GetParallelProjection():
        cam.SetParallelScale(cam.GetParallelScale() / factor)
    else:
        pos = np.array(cam.GetPosition(), float)
        cam.SetPosition(*(pos + step * (target - pos)))
    cam.SetFocalPoint(*(fp + step * (target - fp)))
    renderer.ResetCameraClippingRange()
