"""Bounded, seeded samples of big clouds, for the figures where full resolution buys nothing.

A real TLS scan of one tree holds millions of points; its height, DBH and crown
width come out the same, within the measurement's own scatter, from a few hundred
thousand of them. :func:`measure_pair` measures the registered pair on a seeded
random sample of at most :data:`MEASURE_MAX_POINTS` points per scan (a random sample
keeps the scan's density pattern, which the bark test's 12-neighbour normals depend
on; a voxel grid would not). Scans at or under the bound are measured whole. Exports
always use every point. The bound is set so that a sample's figures differ from the
whole cloud's by no more than the stem fit's own scatter.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Protocol

import numpy as np

from amrst.types import local_transform

if TYPE_CHECKING:
    from amrst.measure import MeasureParams, TreeMeasures
    from amrst.progress import Reporter
    from amrst.types import Cloud, Transform

#: Points per scan the tree measurements use at most (a seeded random sample above).
MEASURE_MAX_POINTS = 200_000


class TreeOf(Protocol):
    """A scan's tree of interest among its ground, neighbours and shrubs."""

    @property
    def tree_share(self) -> float | None:
        """The tree's share of the scan's points; None when the scan is the tree."""

    def on_tree(self, xyz: np.ndarray) -> np.ndarray:
        """(M,) bool: which of these points (local, as the scan's) are the tree's."""


def strided(xyz: np.ndarray, max_points: int) -> np.ndarray:
    """Every k-th row of ``xyz``, about ``max_points`` of them (all when fewer).

    For a figure of the whole cloud (a range, a height span) where a random sample's
    cost buys nothing: a scan's rows follow its sweep, so a stride spreads evenly.
    """
    return xyz[:: max(1, len(xyz) // max(1, max_points))]


def random_rows(
    rows: np.ndarray,
    n: int,
    rng: np.random.Generator | int = 0,
    *,
    in_order: bool = False,
) -> np.ndarray:
    """Return ``rows`` itself when it has at most ``n`` rows, else ``n`` of them at random.

    Parameters
    ----------
    rows : array
        Picked along its first axis.
    n : int
        The most rows returned.
    rng : Generator or int
        A seed (the same rows and seed give the same sample), or a generator to draw
        from (so successive calls pick differently).
    in_order : bool
        Keep the picked rows in their order in ``rows``; else they come in the
        random order drawn.

    Returns
    -------
    array
        A uniform random sample without replacement.
    """
    if len(rows) <= n:
        return rows
    pick = np.random.default_rng(rng).choice(len(rows), n, replace=False)
    return rows[np.sort(pick) if in_order else pick]


def bounded_sample(cloud: Cloud, max_points: int, seed: int = 0) -> Cloud:
    """Return ``cloud`` itself when it has at most ``max_points`` points, else a sample.

    Parameters
    ----------
    cloud : Cloud
    max_points : int
        The bound (>= 1).
    seed : int
        Seed of the sample; the same cloud and seed give the same sample.

    Returns
    -------
    Cloud
        The points of a uniform random sample without replacement, in file order,
        with their attributes.
    """
    if max_points < 1:
        raise ValueError(f"max_points must be >= 1, not {max_points}")
    if len(cloud) <= max_points:
        return cloud
    pick = np.random.default_rng(seed).choice(len(cloud), max_points, replace=False)
    return cloud.select(np.sort(pick))


def measure_pair(
    target: Cloud,
    source: Cloud,
    T_target_source: Transform,
    params: MeasureParams | None = None,
    max_points: int = MEASURE_MAX_POINTS,
    reporter: Reporter | None = None,
    *,
    trees: tuple[TreeOf | None, TreeOf | None] = (None, None),
) -> dict[str, TreeMeasures]:
    """Measure target, moved source and merged tree on bounded samples of the scans.

    Parameters
    ----------
    target, source : Cloud
        The scans as read.
    T_target_source : (4, 4) float64
        World-frame transform from source to target.
    params : MeasureParams, optional
    max_points : int
        Points per scan at most (see :data:`MEASURE_MAX_POINTS`).
    reporter : Reporter, optional
        Checked for Cancel between the measurements (the app's steps).
    trees : (TreeOf or None, TreeOf or None)
        For a scan with ground, neighbours or shrubs, its tree of interest
        (``ScanAnalysis``): only its points are measured (:func:`tree_sample`).

    Returns
    -------
    dict
        What :func:`amrst.measure.measure_registration` returns: ``n_points`` is
        each cloud's size (its tree's share of it), ``n_points_measured`` the sample
        measured.
    """
    from amrst.measure import measure_registration
    from amrst.progress import NULL_REPORTER

    target_part, n_target = tree_sample(target, trees[0], max_points, seed=0)
    source_part, n_source = reference_tree_sample(
        source, trees[1], (target, trees[0]), T_target_source, max_points, seed=1
    )
    return measure_registration(
        target_part,
        source_part,
        T_target_source,
        params,
        reporter=reporter or NULL_REPORTER,
        sizes=(n_target, n_source),
    )


#: A scan's tree of interest is the reference's when at least this share of its
#: points lies on the reference's tree once registered.
SAME_TREE_SHARE = 0.5


def reference_tree_sample(
    cloud: Cloud,
    tree: TreeOf | None,
    reference: tuple[Cloud, TreeOf | None],
    T_world: Transform,
    max_points: int,
    seed: int = 0,
) -> tuple[Cloud, int]:
    """:func:`tree_sample` of the reference scan's tree of interest in ``cloud``.

    ``reference`` is the reference scan and its tree of interest; ``T_world`` takes
    ``cloud``'s world coordinates into the reference's. The scan's own tree of
    interest is taken when it is the reference's (most of its points lie on the
    reference's tree once registered); otherwise, as in a plot, where the stem
    nearest each scan's middle is another tree, the scan's points that the
    reference's segmentation gives its tree are.
    """
    part, size = tree_sample(cloud, tree, max_points, seed)
    ref_cloud, ref_tree = reference
    if not (tree and tree.tree_share and ref_tree and ref_tree.tree_share):
        return part, size  # a clean tree on either side: nothing to tell apart
    seen = _ReferenceTree(ref_tree, local_transform(T_world, ref_cloud, cloud))
    if not len(part) or seen.on_tree(part.xyz).mean() >= SAME_TREE_SHARE:
        return part, size
    seen.share = float(seen.on_tree(bounded_sample(cloud, max_points, seed).xyz).mean())
    if not seen.share:  # none of its points on the reference's tree: keep its own
        return part, size
    return tree_sample(cloud, seen, max_points, seed)


class _ReferenceTree:
    """The reference scan's tree of interest, asked of another scan's points.

    ``T_local`` takes the scan's local coordinates into the reference's.
    """

    def __init__(self, tree: TreeOf, T_local: Transform) -> None:
        self.tree, self.share = tree, 0.0
        self.R, self.t = T_local[:3, :3], T_local[:3, 3]

    @property
    def tree_share(self) -> float | None:
        return self.share

    def on_tree(self, xyz: np.ndarray) -> np.ndarray:
        return self.tree.on_tree(np.asarray(xyz, float) @ self.R.T + self.t)


#: A tree under this share of its scan is sampled as if it held this share: the
#: sample grows to max_points / share at most, and the tree's points in it with it.
MIN_TREE_SHARE = 0.05


def tree_sample(
    cloud: Cloud, tree: TreeOf | None, max_points: int, seed: int = 0
) -> tuple[Cloud, int]:
    """Return up to about ``max_points`` of the tree's points, and its size in ``cloud``.

    Without ``tree``, a bounded sample of the whole cloud. With one, a sample of the
    cloud large enough to hold about ``max_points`` of the tree's points (the tree's
    share of the scan's working points says how large, down to
    :data:`MIN_TREE_SHARE`), kept to those; the size is the cloud's times the share
    of the sample kept.
    """
    share = None if tree is None else tree.tree_share
    if tree is None or not share:  # no tree set apart: the scan is measured whole
        return bounded_sample(cloud, max_points, seed), len(cloud)
    drawn = bounded_sample(cloud, int(max_points / max(share, MIN_TREE_SHARE)), seed)
    keep = tree.on_tree(drawn.xyz)
    part = drawn.select(np.flatnonzero(keep))
    size = round(len(cloud) * float(keep.mean())) if len(keep) else 0
    return bounded_sample(part, max_points, seed), size
