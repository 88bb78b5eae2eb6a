"""A registered scan's residual: its distance to the other scans' surfaces."""

from __future__ import annotations

import _plots
import numpy as np
from scipy.spatial.transform import Rotation

from amrst.plot.register import analyse_plot, register_plot
from amrst.plot.residual import Surfaces, bundle_error, scan_residuals
from amrst.types import Cloud, make_transform


def _ground_and_stem(step: float, shift: float) -> np.ndarray:
    """A 6 m ground and a 30 cm stem, sampled every ``step`` from ``shift``."""
    g = np.arange(-3 + shift, 3, step)
    gx, gy = np.meshgrid(g, g)
    ground = np.column_stack([gx.ravel(), gy.ravel(), np.zeros(gx.size)])
    a = np.arange(0 + shift, 2 * np.pi, step / 0.15)
    z = np.arange(0.2 + shift, 3, step)
    aa, zz = np.meshgrid(a, z)
    stem = np.column_stack(
        [1 + 0.15 * np.cos(aa.ravel()), 0.15 * np.sin(aa.ravel()), zz.ravel()]
    )
    return np.vstack([ground, stem])


def test_the_residual_is_the_distance_between_surfaces_not_between_points() -> None:
    # Two samplings of the same surfaces, 5 cm apart and offset by half of it: their
    # points lie about 3 cm from one another, their surfaces on one another.
    a, b = _ground_and_stem(0.05, 0.0), _ground_and_stem(0.05, 0.025)
    surfaces = Surfaces([a, b])
    same = scan_residuals(surfaces, [np.eye(4), np.eye(4)])
    assert max(same) < 0.002
    up = make_transform(np.eye(3), np.array([0.0, 0.0, 0.02]))  # 2 cm too high
    raised = scan_residuals(surfaces, [np.eye(4), up])
    assert all(0.015 < r < 0.025 for r in raised)
    assert np.isclose(surfaces.residual(1, {0: up}), raised[1])  # a link's
    assert np.isclose(bundle_error(raised), np.sqrt(np.mean(np.square(raised))))


def test_a_scan_not_placed_or_alone_has_no_residual() -> None:
    a = _ground_and_stem(0.05, 0.0)
    r = scan_residuals(Surfaces([a, a + 0.01, a]), [np.eye(4), None, np.eye(4)])
    assert np.isnan(r[1])
    assert np.isfinite([r[0], r[2]]).all()
    alone = scan_residuals(Surfaces([a, a]), [np.eye(4), None])
    assert all(np.isnan(alone))
    assert np.isnan(bundle_error(alone))
    far = make_transform(np.eye(3), np.array([100.0, 0.0, 0.0]))  # no overlap
    assert all(np.isnan(scan_residuals(Surfaces([a, a]), [np.eye(4), far])))


def test_a_registered_plot_gives_each_scan_a_residual_that_grows_off_its_pose() -> None:
    target, source, T_true = _plots.plot_pair()
    scans = analyse_plot([Cloud(target), Cloud(source)])
    reg = register_plot(scans)
    assert len(reg.residuals_m) == 2
    assert all(0 < r < 0.02 for r in reg.residuals_m)
    assert reg.bundle_rmse_m == bundle_error(reg.residuals_m)
    assert 0 < reg.links[0].residual_m < 0.02  # the source on the target's surfaces
    points = Surfaces([s.analysis.cloud.xyz for s in scans])
    right = scan_residuals(points, [np.eye(4), T_true])
    turn = Rotation.from_euler("z", 1.0, degrees=True).as_matrix()
    off = make_transform(turn, np.array([0.1, 0.0, 0.0])) @ T_true  # 1 deg, 10 cm
    wrong = scan_residuals(points, [np.eye(4), off])
    assert wrong[1] > 2 * right[1]
