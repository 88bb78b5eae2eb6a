"""Frame match (F) aims both views at the selected tetrahedron and fills them with it."""

from __future__ import annotations

import numpy as np


def _projected(view, xyz: np.ndarray) -> np.ndarray:
    """(K, 2) view coordinates of points: -1..1 across the view."""
    ren = view.plotter.renderer
    out = []
    for p in xyz:
        ren.SetWorldPoint(*p, 1.0)
        ren.WorldToView()
        out.append(ren.GetViewPoint()[:2])
    return np.asarray(out)


def _distance(view) -> float:
    cam = view.plotter.camera
    return float(np.linalg.norm(np.subtract(cam.position, cam.focal_point)))


def _vertices(view) -> np.ndarray:
    return next(ly.centers for ly in view.scene.layers if ly.name == "match_vertices")


def _check_framed(view) -> None:
    verts = _vertices(view)
    centre = (verts.min(axis=0) + verts.max(axis=0)) / 2
    np.testing.assert_allclose(view.plotter.camera.focal_point, centre, atol=1e-6)
    xy = _projected(view, verts)
    assert np.all(np.abs(xy) <= 1.0), f"a vertex is out of sight: {xy}"
    # At least a quarter of the view across (a small one keeps some tree around).
    assert np.ptp(xy, axis=0).max() > 0.5, f"the tetrahedron is small in view: {xy}"


def test_frame_match_fills_the_views_with_the_selected_tetrahedron(
    loaded_window, finish
):
    win = loaded_window
    s, a = win.session, win.actions
    finish(s, a.separate.trigger, "separation_finished")
    finish(s, a.skeleton.trigger, "skeletons_finished")
    finish(s, a.match.trigger, "matches_changed")
    views = win.scans_area.views()
    whole_tree = {v: _distance(v) for v in views}

    # The top match spans the whole tree (root to crown): framed, not zoomed out.
    win.scans_area.frame_button.click()
    for view in views:
        _check_framed(view)
        assert _distance(view) <= 1.05 * whole_tree[view]

    # The smallest tetrahedron among the candidates: the views come much closer.
    def span(c):
        kp = s.analysis("target").keypoints.xyz
        return np.ptp(kp[np.asarray(c.target_idx)], axis=0).max()

    small = min((c for c in s.matches if len(c.target_idx) == 4), key=span)
    s.select_match(small.id)
    win.scans_area.reset_cameras()
    win.scans_area.frame_button.click()
    for view in views:
        _check_framed(view)
        assert _distance(view) < 0.8 * whole_tree[view]
