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

from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    from collections.abc import Callable

    from amrst.measure import MeasureParams, TreeMeasures
    from amrst.progress import Reporter
    from amrst.types import Cloud, Transform

#: Points per scan the tree measurements use at most (a seeded random sample above).
MEASURE_MAX_POINTS = 200_000

if TYPE_CHECKING:
    #: Which of a scan's points (local, (M, 3)) are its tree's: (M,) bool, None: all.
    OnTree = Callable[[np.ndarray], np.ndarray | None]


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
    on_tree: tuple[OnTree | None, OnTree | None] = (None, None),
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
    on_tree : (callable or None, callable or None)
        For a scan with ground, neighbours or shrubs, which of its points are the
        tree of interest's (``ScanAnalysis.on_tree``); only those are measured.

    Returns
    -------
    dict
        What :func:`amrst.measure.measure_registration` returns: ``n_points`` is
        each cloud's size (its tree's share of it), ``n_points_measured`` the sample
        measured.
    """
    from amrst.measure import measure_registration
    from amrst.progress import NULL_REPORTER

    samples, sizes = [], []
    for seed, (cloud, pick) in enumerate(zip((target, source), on_tree, strict=True)):
        sample = bounded_sample(cloud, max_points, seed=seed)
        keep = None if pick is None or not len(sample) else pick(sample.xyz)
        if keep is not None:
            sample = sample.select(np.flatnonzero(keep))
        samples.append(sample)
        sizes.append(len(cloud) if keep is None else round(len(cloud) * keep.mean()))
    return measure_registration(
        samples[0],
        samples[1],
        T_target_source,
        params,
        reporter=reporter or NULL_REPORTER,
        sizes=(sizes[0], sizes[1]),
    )
