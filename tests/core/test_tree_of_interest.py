"""The tree a registration measures is the reference scan's tree of interest in
every scan, even when another scan's own pick is another tree (a plot)."""

from __future__ import annotations

import numpy as np

from amrst.sampling import reference_tree_sample
from amrst.types import Cloud, make_transform


class _Near:
    """A tree of interest: the points within 1 m (horizontally) of ``xy``."""

    def __init__(self, xy: tuple[float, float], share: float = 0.5) -> None:
        self.xy, self.tree_share = np.asarray(xy, float), share

    def on_tree(self, xyz: np.ndarray) -> np.ndarray:
        return np.hypot(*(np.asarray(xyz)[:, :2] - self.xy).T) < 1.0


def _two_trees(rng: np.random.Generator, shift: np.ndarray, offset) -> Cloud:
    """Two stems, at (0, 0) and (5, 0) in the reference's world frame, seen from a
    scan whose world frame is the reference's moved by ``shift``, its points local
    to ``offset`` (a georeferenced file's)."""
    stems = [rng.normal([x, 0.0, 2.0], [0.2, 0.2, 1.0], (2000, 3)) for x in (0, 5)]
    offset = np.asarray(offset, float)
    return Cloud(np.vstack(stems) - shift - offset, offset=offset)


def test_a_scan_whose_pick_is_another_tree_gives_its_points_of_the_reference_s():
    rng = np.random.default_rng(0)
    shift = np.array([1.0, 2.0, 0.0])  # the scan's frame: the reference's, moved
    ref_at, scan_at = np.array([500.0, 300.0, 0.0]), np.array([-20.0, 40.0, 0.0])
    reference = _two_trees(rng, np.zeros(3), ref_at)
    scan = _two_trees(rng, shift, scan_at)
    T = make_transform(np.eye(3), shift)  # scan -> reference, world coordinates
    ref_tree = _Near((0.0, 0.0) - ref_at[:2])  # trees answer in local coordinates
    # The scan picked the other stem: the reference's is measured in it instead.
    other = _Near((5.0, 0.0) - shift[:2] - scan_at[:2])
    part, _ = reference_tree_sample(scan, other, (reference, ref_tree), T, 10_000)
    moved = part.xyz + scan_at + shift
    assert len(part) > 1000
    assert np.all(np.hypot(*moved[:, :2].T) < 1.0)
    # The scan picked the same stem: its own pick stands.
    same = _Near((0.0, 0.0) - shift[:2] - scan_at[:2])
    part, _ = reference_tree_sample(scan, same, (reference, ref_tree), T, 10_000)
    np.testing.assert_array_equal(
        np.sort(part.xyz, axis=0), np.sort(scan.xyz[same.on_tree(scan.xyz)], axis=0)
    )
    # A clean tree (no tree set apart) is measured whole, as before.
    whole = _Near((0.0, 0.0), share=None)  # type: ignore[arg-type]
    part, size = reference_tree_sample(scan, whole, (reference, ref_tree), T, 10_000)
    assert size == len(scan)


def test_a_scan_cut_around_a_given_stem_is_measured_inside_the_cut():
    # Two stems 12 m apart and no ground: with the first one given, the scan is cut
    # 6 m around it, and what is measured is the cut, not the whole scan.
    from amrst.params import RegistrationParams
    from amrst.pipeline.analysis import prepare_scan

    rng = np.random.default_rng(1)
    stems = [rng.normal([x, 0.0, 4.0], [0.15, 0.15, 2.0], (3000, 3)) for x in (0, 12)]
    scan = Cloud(np.vstack(stems))
    analysis = prepare_scan(scan, RegistrationParams(), stem_xy=np.zeros(2))
    assert analysis.scene is not None
    assert not analysis.scene.has_ground
    on = analysis.on_tree(scan.xyz)
    assert np.mean(on[:3000]) > 0.98  # the given stem (stray points aside)
    assert not on[3000:].any()  # the other stem, outside the cut
    assert analysis.tree_share is not None
    assert 0.4 < analysis.tree_share < 0.6
    # Without a stem given, a scan without ground is one tree: all of it.
    whole = prepare_scan(scan, RegistrationParams())
    assert whole.tree_share is None
    assert whole.on_tree(scan.xyz).all()
