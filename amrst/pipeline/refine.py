"""Fine registration of a link from a coarse solution, and the link's cloud metrics."""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np

from amrst.neighbours import THREADS
from amrst.progress import NULL_REPORTER, Reporter
from amrst.review.overlap import OverlapDistances, overlap_distances
from amrst.review.quality import StemSlice, stem_slices
from amrst.review.strength import Strength, axis_strength
from amrst.stages.coarse import CoarseResult
from amrst.stages.fine import FineResult, refine_registration
from amrst.stages.metrics import CloudMetrics, measure_clouds

if TYPE_CHECKING:
    from amrst.params import RegistrationParams
    from amrst.pipeline.analysis import ScanAnalysis
    from amrst.pipeline.link import MatchResult
    from amrst.types import Transform


def refine(
    target: ScanAnalysis,
    source: ScanAnalysis,
    start: Transform | CoarseResult,
    params: RegistrationParams,
    reporter: Reporter = NULL_REPORTER,
    matches: MatchResult | None = None,
    *,
    threads: int = THREADS,
) -> FineResult:
    """Fine registration from a coarse local-frame transform or an accepted coarse result.

    A coarse result from the trunk heading search is refined on the point set its
    verification chose (``Candidate.fine_points``); anything else on ``fine.points``.
    When ``matches`` already holds this candidate's full fine registration (the trunk
    search makes one while verifying), that result is returned instead of a second run.
    ``threads``: for the KD-tree queries.
    """
    which = params.fine.points
    if isinstance(start, CoarseResult):
        if matches is not None and start.candidate.id in matches.refined:
            reporter.progress(1.0, "already refined while verifying")
            return matches.refined[start.candidate.id]
        T_init = start.T_target_source
        if start.candidate.fine_points:
            which = start.candidate.fine_points
    else:
        T_init = start
    return refine_registration(
        target.points(which),
        source.points(which),
        T_init,
        params.fine,
        reporter,
        threads=threads,
    )


def evaluate(
    target: ScanAnalysis,
    source: ScanAnalysis,
    T_target_source: Transform,
    params: RegistrationParams,
    *,
    threads: int = THREADS,
) -> CloudMetrics:
    """NN-RMSE, Hausdorff and overlap of the preprocessed scans under a local-frame transform."""
    moved = source.xyz @ T_target_source[:3, :3].T + T_target_source[:3, 3]
    return measure_clouds(target.xyz, moved, params.metrics, threads=threads)


@dataclass(frozen=True, slots=True)
class PoseQuality:
    """What a technician judges one pose by.

    Attributes
    ----------
    overlap : OverlapDistances
        Distances from the moved source to the target where both scans saw the scene.
    strength : Strength
        How firmly the pose holds each of its six axes.
    slices : tuple of StemSlice
        Stem slices of the tree of interest alone (ground, neighbours, shrubs out).
    """

    overlap: OverlapDistances
    strength: Strength
    slices: tuple[StemSlice, ...]

    def section(self) -> dict[str, Any]:
        """Return the ``quality`` section of metrics.json (distance, stem slices)."""
        return {
            "distance": self.overlap.as_dict(),
            "stem_slices": [s.as_dict() for s in self.slices],
        }


def pose_quality(
    target: ScanAnalysis,
    source: ScanAnalysis,
    T_target_source: Transform,
    params: RegistrationParams,
) -> PoseQuality:
    """Measure a local-frame pose as the CLI, the app and the reports judge it."""
    T = np.asarray(T_target_source, float)
    R, t = T[:3, :3], T[:3, 3]
    return PoseQuality(
        overlap=overlap_distances(target.xyz, source.xyz, T),
        strength=axis_strength(
            target.xyz, source.xyz, T, params.metrics.overlap_dist_m
        ),
        slices=tuple(stem_slices(target.tree_xyz, source.tree_xyz @ R.T + t)),
    )
