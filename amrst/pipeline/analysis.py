"""Per-scan analysis: preprocess, wood/leaf separation, skeleton and key points.

Each scan is analysed once, whatever number of links (scan pairs) it takes part in;
:func:`both_scans` runs the two scans of a pair, one after the other. Everything here works in the
scan's own local coordinates (``Cloud.xyz``).
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field, replace
from typing import TYPE_CHECKING, TypeVar

import numpy as np

from amrst.errors import InvalidInput
from amrst.neighbours import THREADS
from amrst.progress import NULL_REPORTER, Reporter, SubReporter
from amrst.stages.keypoints import KeypointResult, extract_keypoints
from amrst.stages.preprocess import PreprocessResult, preprocess_points
from amrst.stages.scene import GROUND, OUTSIDE, TREE, SceneResult, understand_scene
from amrst.stages.separate import SeparationResult, separate_wood
from amrst.stages.skeleton import SkeletonResult, build_skeleton

if TYPE_CHECKING:
    from collections.abc import Callable

    from amrst.params import RegistrationParams
    from amrst.types import Cloud

#: The ground this near the tree's stem base (m) is measured with the tree: the
#: base is found on it, as on a scan of the tree alone.
BASE_GROUND_M = 1.0
#: Points farther than this outside the box of the tree's working points (m) are not
#: the tree's (a thinned point stands for raw points a voxel around it).
BOX_MARGIN_M = 0.5

_Item = TypeVar("_Item")
_Out = TypeVar("_Out")


@dataclass(frozen=True, slots=True)
class ScanAnalysis:
    """One scan after the per-scan stages; later fields are None until computed."""

    cloud: Cloud
    pre: PreprocessResult
    separation: SeparationResult
    skeleton: SkeletonResult | None = None
    keypoints: KeypointResult | None = None
    timings: dict[str, float] = field(default_factory=dict)
    # Scene labels of every preprocessed point (``scene_pre``); ``pre`` keeps only the
    # points the tree stages use (scene.use_points). None when not computed.
    scene: SceneResult | None = None
    scene_pre: PreprocessResult | None = None

    @property
    def xyz(self) -> np.ndarray:
        """(N, 3) preprocessed points, local coordinates."""
        return self.pre.xyz

    @property
    def is_wood(self) -> np.ndarray:
        """(N,) bool wood label of the preprocessed points."""
        return self.separation.is_wood

    @property
    def tree_xyz(self) -> np.ndarray:
        """(K, 3) points of the tree of interest alone, local coordinates.

        Without ground, neighbours and shrubs; all preprocessed points when the scene
        stage found no ground (a clean, segmented tree).
        """
        scene, pre = self.scene, self.scene_pre
        if scene is None or pre is None or not scene.has_ground:
            return self.xyz
        return np.asarray(pre.xyz[scene.labels == TREE])

    def _tree_labels(self) -> np.ndarray | None:
        """Mark the tree of interest's working points (``scene_pre``).

        With the ground under its stem, on which its base is measured; None when the
        scan is that tree alone. A scan cut around a given stem is never that: what
        lies inside the cut is the tree when no ground was found there.
        """
        scene, pre = self.scene, self.scene_pre
        if scene is None or pre is None or not len(pre.xyz):
            return None
        if not scene.has_ground and not (scene.labels == OUTSIDE).any():
            return None
        keep = scene.labels == TREE
        if scene.base is not None:
            foot = np.hypot(*(pre.xyz[:, :2] - scene.base[:2]).T) <= BASE_GROUND_M
            keep |= (scene.labels == GROUND) & foot
        return np.asarray(keep)

    @property
    def tree_share(self) -> float | None:
        """The tree of interest's share of the working points (``on_tree``'s).

        None when the scan is that tree alone (no ground found), as a clean tree is.
        """
        keep = self._tree_labels()
        return None if keep is None else float(keep.mean())

    def on_tree(self, xyz: np.ndarray) -> np.ndarray:
        """Tell which points (local, as this scan's) are the tree of interest's.

        Returns (M,) bool: those whose nearest working point is the tree's, or the
        ground under its stem; every point when the scan is that tree alone.
        """
        from amrst.neighbours import knn

        keep, pre = self._tree_labels(), self.scene_pre
        xyz = np.asarray(xyz, float).reshape(-1, 3)
        if keep is None or pre is None:
            return np.ones(len(xyz), dtype=bool)
        out = np.zeros(len(xyz), dtype=bool)
        if not keep.any():
            return out
        # Only points near the tree's box can be nearest one of its points.
        mine = pre.xyz[keep]
        lo, hi = mine.min(axis=0) - BOX_MARGIN_M, mine.max(axis=0) + BOX_MARGIN_M
        near = np.flatnonzero(np.all((xyz >= lo) & (xyz <= hi), axis=1))
        if len(near):
            _, nearest = knn(pre.xyz, 1, xyz[near])
            out[near] = keep[nearest[:, 0]]
        return out

    def points(self, which: str) -> np.ndarray:
        """Preprocessed points: 'all', 'wood' or 'leaf' (falls back to all when too few)."""
        if which == "all":
            return self.xyz
        sel = self.xyz[self.is_wood if which == "wood" else ~self.is_wood]
        return sel if len(sel) >= 100 else self.xyz


# Neighbours listed per point by the preprocess query beyond what the later stages
# ask for: the wood features and the skeleton graph read theirs off that table where
# enough of the listed points are left in their subset (see NeighbourTable).
SHARED_MARGIN = 2


def _shared_k(params: RegistrationParams, skeleton: bool) -> int:
    """Neighbours per point the preprocess query lists for the later stages.

    0 when no later stage reads them: no wood-leaf separation, and no skeleton.
    """
    need = 0
    if params.separate.mode != "all_wood":
        need = max(*params.separate.scales_k, params.separate.vote_neighbours)
    if skeleton:
        need = max(need, max(params.skeleton.neighbours, 16) + 1)
    return need + SHARED_MARGIN if need else 0


def _timed(timings: dict[str, float], key: str, t0: float) -> float:
    now = time.perf_counter()
    timings[key] = timings.get(key, 0.0) + now - t0
    return now


def prepare_scan(
    cloud: Cloud,
    params: RegistrationParams,
    reporter: Reporter = NULL_REPORTER,
    stem_xy: np.ndarray | None = None,
    expect_ground: float | None = None,
    pre: PreprocessResult | None = None,
    *,
    skeleton: bool = True,
    threads: int = THREADS,
) -> ScanAnalysis:
    """Preprocess one scan, label its scene, and separate wood from leaves.

    ``stem_xy`` (local frame) picks the tree of interest; ``expect_ground`` is the
    other scan's ground tilt (deg) when it has a ground (see ``understand_scene``).
    ``pre``: this scan's preprocessing made before with the same parameters (an
    earlier analysis's ``scene_pre``), used instead of a new one. ``skeleton``:
    :func:`skeletonise_scan` follows, and the preprocess lists the neighbours it
    reads. ``threads``: for the KD-tree queries.
    """
    timings: dict[str, float] = {}
    t0 = time.perf_counter()
    if pre is None:
        try:
            pre = preprocess_points(
                cloud.xyz,
                params.preprocess,
                SubReporter(reporter, 0, 0.3, "preprocess"),
                share_k=_shared_k(params, skeleton),
                threads=threads,
            )
        except InvalidInput as exc:  # say which scan
            raise InvalidInput(f"{cloud.name or 'scan'}: {exc}") from exc
    t0 = _timed(timings, "preprocess", t0)
    # Ground, neighbours and shrubs (field scans); a clean tree stays as it is.
    scene = understand_scene(
        pre.xyz, params.scene, stem_xy, expect_ground, ground_xyz=cloud.xyz
    )
    full_pre = pre
    keep = scene.keep(params.scene.use_points)
    if not keep.all() and keep.sum() >= params.preprocess.min_points:
        kept = np.flatnonzero(keep)
        table = None if pre.neighbours is None else pre.neighbours.subset(kept)
        pre = replace(pre, xyz=pre.xyz[kept], index=pre.index[kept], neighbours=table)
    t0 = _timed(timings, "scene", t0)
    reporter.progress(0.35, scene.message)
    intensity = cloud.intensity
    sep = separate_wood(
        pre.xyz,
        None if intensity is None else intensity[pre.index],
        params.separate,
        SubReporter(reporter, 0.3, 1.0, "wood-leaf separation"),
        pre.neighbours,
        threads=threads,
    )
    _timed(timings, "separate", t0)
    return ScanAnalysis(
        cloud, pre, sep, timings=timings, scene=scene, scene_pre=full_pre
    )


def skeletonise_scan(
    analysis: ScanAnalysis,
    params: RegistrationParams,
    reporter: Reporter = NULL_REPORTER,
    *,
    threads: int = THREADS,
) -> ScanAnalysis:
    """Add the skeleton and the key points to a prepared scan.

    ``threads``: for the KD-tree queries.
    """
    timings = dict(analysis.timings)
    t0 = time.perf_counter()
    pts = analysis.points(params.skeleton.points)
    if len(pts) < params.skeleton.min_points:
        pts = analysis.xyz
    table = analysis.pre.neighbours
    if table is not None and len(pts) != len(table):  # the wood points alone
        table = table.subset(np.flatnonzero(analysis.is_wood))
    skel = build_skeleton(
        pts,
        params.skeleton,
        SubReporter(reporter, 0, 0.9, "skeleton"),
        table,
        threads=threads,
    )
    t0 = _timed(timings, "skeleton", t0)
    kp = extract_keypoints(skel, params.keypoints)
    _timed(timings, "keypoints", t0)
    reporter.progress(1.0, f"{len(kp.xyz)} key points")
    return replace(analysis, skeleton=skel, keypoints=kp, timings=timings)


def analyse_scan(
    cloud: Cloud,
    params: RegistrationParams,
    reporter: Reporter = NULL_REPORTER,
    stem_xy: np.ndarray | None = None,
    expect_ground: float | None = None,
    pre: PreprocessResult | None = None,
    *,
    threads: int = THREADS,
) -> ScanAnalysis:
    """Run every per-scan step: :func:`prepare_scan`, then :func:`skeletonise_scan`.

    The order is the step table's (``amrst.pipeline.steps.STEPS``, its ``per_scan``
    entries); a test keeps the two in agreement. ``pre`` and ``threads`` as in
    :func:`prepare_scan`.
    """
    an = prepare_scan(
        cloud,
        params,
        SubReporter(reporter, 0.0, 0.7),
        stem_xy,
        expect_ground,
        pre,
        threads=threads,
    )
    return skeletonise_scan(
        an, params, SubReporter(reporter, 0.7, 1.0), threads=threads
    )


def both_scans(
    fn: Callable[[_Item, Reporter], _Out],
    target_item: _Item,
    source_item: _Item,
    reporter: Reporter = NULL_REPORTER,
) -> tuple[_Out, _Out]:
    """Run ``fn(item, reporter)`` for the target's item, then for the source's.

    Returns ``(target result, source result)``; each reports on its half of
    ``reporter``'s range, named. One after the other, not at once: every step already
    runs its KD-tree queries on all the threads it is given.
    """
    target = fn(target_item, SubReporter(reporter, 0.0, 0.5, "target"))
    return target, fn(source_item, SubReporter(reporter, 0.5, 1.0, "source"))
