"""``register()``: the whole chain for one pair of scans, as the CLI runs it."""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np

from amrst.errors import InvalidInput
from amrst.neighbours import THREADS
from amrst.params import RegistrationParams
from amrst.pipeline.analysis import ScanAnalysis, analyse_scan, both_scans
from amrst.pipeline.link import MatchResult, coarse_from_matches, find_matches
from amrst.pipeline.refine import evaluate, pose_quality, refine
from amrst.progress import NULL_REPORTER, Reporter, SubReporter
from amrst.sampling import measure_pair
from amrst.types import world_transform

#: How far beyond a scan's points a stem given by hand may stand (m).
STEM_REACH_M = 5.0

if TYPE_CHECKING:
    from amrst.measure import TreeMeasures
    from amrst.review.overlap import OverlapDistances
    from amrst.review.quality import StemSlice
    from amrst.review.strength import Strength
    from amrst.stages.coarse import CoarseResult
    from amrst.stages.fine import FineResult
    from amrst.stages.metrics import CloudMetrics
    from amrst.types import Cloud, Transform


@dataclass(frozen=True, slots=True)
class RegistrationResult:
    """Everything register() found, for display, export and the benchmark."""

    T_target_source: Transform  # world frame, after fine registration
    T_coarse: Transform  # world frame, coarse solution
    confidence: float
    message: str
    target: ScanAnalysis
    source: ScanAnalysis
    matches: MatchResult
    coarse: CoarseResult
    fine: FineResult
    metrics_coarse: CloudMetrics
    metrics_fine: CloudMetrics
    timings: dict[str, float]  # stage -> seconds, with "total"
    params: RegistrationParams
    # Height, DBH and crown of "target", "source" (moved) and "merged"; scans over
    # amrst.sampling.MEASURE_MAX_POINTS points are measured on a seeded sample.
    tree: dict[str, TreeMeasures] = field(default_factory=dict)
    # Distances where both scans saw the scene above the ground, and how firmly
    # the final pose holds each axis: what a technician judges the result by.
    overlap: OverlapDistances | None = None
    strength: Strength | None = None
    # Stem slices of the tree of interest (ground, neighbours and shrubs out).
    slices: tuple[StemSlice, ...] = ()


def _expect_ground(
    tgt: ScanAnalysis,
    src: ScanAnalysis,
    params: RegistrationParams,
    rep: Reporter,
    stems: tuple[np.ndarray | None, np.ndarray | None],
    threads: int,
) -> tuple[ScanAnalysis, ScanAnalysis]:
    """Analyse again the scan that found no ground when the other one found one.

    Both scans of a pair were made in one place: a scan half hidden by a neighbour
    may show too little ground to tell from a stem foot on its own, but enough once
    the other scan has a ground (``scene.expected_ground_area_m2``). ``stems``: each
    scan's stem (local frame) or None.
    """
    t_scene, s_scene = tgt.scene, src.scene
    if t_scene is None or s_scene is None or t_scene.has_ground == s_scene.has_ground:
        return tgt, src
    # The preprocessing does not depend on the ground expected: it is reused.
    if t_scene.has_ground:
        tilt, cloud, stem, pre = (
            t_scene.ground_tilt_deg,
            src.cloud,
            stems[1],
            src.scene_pre,
        )
    else:
        tilt, cloud, stem, pre = (
            s_scene.ground_tilt_deg,
            tgt.cloud,
            stems[0],
            tgt.scene_pre,
        )
    again = analyse_scan(cloud, params, rep, stem, tilt, pre, threads=threads)
    return (tgt, again) if t_scene.has_ground else (again, src)


def register(
    target: Cloud,
    source: Cloud,
    params: RegistrationParams | None = None,
    reporter: Reporter | None = None,
    stems: tuple[np.ndarray | None, np.ndarray | None] = (None, None),
    *,
    threads: int = THREADS,
) -> RegistrationResult:
    """Register ``source`` onto ``target`` (the whole AMRST chain).

    Parameters
    ----------
    target : Cloud
        The reference scan.
    source : Cloud
        The scan to move.
    params : RegistrationParams or None
        Defaults when None.
    reporter : Reporter or None
    stems : (target, source) of (2,) float64 or None
        The stem of the tree of interest in each scan, world x y (for whole plot
        scans: the scene stage cuts ``scene.crop_radius_m`` around it); None: the
        stem nearest the middle of the scan.
    threads : int
        Threads for the two scans' analyses and for each KD-tree query; the result
        is the same for any number.

    Returns
    -------
    RegistrationResult
        ``T_target_source`` maps source world coordinates into the target world frame.

    Raises
    ------
    RegistrationFailed
        Too few key points, or no verified candidate.
    Cancelled
        When the reporter asks to stop.
    """
    params = params or RegistrationParams()
    reporter = reporter or NULL_REPORTER
    t_start = time.perf_counter()

    local = {
        id(cloud): None if xy is None else _stem_in(cloud, xy, role)
        for cloud, xy, role in zip(
            (target, source), stems, ("the target", "the source"), strict=True
        )
    }

    def analyse(cloud: Cloud, rep: Reporter) -> ScanAnalysis:
        return analyse_scan(cloud, params, rep, local[id(cloud)], threads=threads)

    scans = SubReporter(reporter, 0.0, 0.6)
    tgt, src = both_scans(analyse, target, source, scans)
    tgt, src = _expect_ground(
        tgt,
        src,
        params,
        SubReporter(reporter, 0.55, 0.6),
        (local[id(target)], local[id(source)]),
        threads,
    )
    matches = find_matches(
        tgt, src, params, SubReporter(reporter, 0.6, 0.85, ""), threads=threads
    )
    coarse = coarse_from_matches(matches)
    t0 = time.perf_counter()
    fine = refine(
        tgt,
        src,
        coarse,
        params,
        SubReporter(reporter, 0.85, 0.95, "fine"),
        matches,
        threads=threads,
    )
    return finish_registration(
        (target, source),
        (tgt, src),
        matches,
        coarse,
        fine,
        params=params,
        reporter=reporter,
        timings={"fine": time.perf_counter() - t0},
        t_start=t_start,
        threads=threads,
    )


def finish_registration(
    clouds: tuple[Cloud, Cloud],
    scans: tuple[ScanAnalysis, ScanAnalysis],
    matches: MatchResult,
    coarse: CoarseResult,
    fine: FineResult,
    *,
    params: RegistrationParams,
    reporter: Reporter,
    timings: dict[str, float],
    t_start: float,
    threads: int = THREADS,
) -> RegistrationResult:
    """Measure a registered pair and gather its :class:`RegistrationResult`.

    The metrics of the coarse and fine poses, the tree of both scans merged, and the
    timings of every stage; shared by the automatic chain and the point-pair one.
    """
    target, source = clouds
    tgt, src = scans
    t0 = time.perf_counter()
    m_coarse = evaluate(tgt, src, coarse.T_target_source, params, threads=threads)
    # A trunk-search solution was fine-registered while it was verified: its coarse
    # and fine transforms are the same, and so are their metrics.
    same = np.array_equal(fine.T_target_source, coarse.T_target_source)
    m_fine = (
        m_coarse
        if same
        else evaluate(tgt, src, fine.T_target_source, params, threads=threads)
    )
    T_world = world_transform(fine.T_target_source, target, source)
    tree = measure_pair(target, source, T_world, params.measure, trees=(tgt, src))
    quality = pose_quality(tgt, src, fine.T_target_source, params)
    all_timings: dict[str, float] = {}
    for an in (tgt, src):
        for k, v in an.timings.items():
            all_timings[k] = all_timings.get(k, 0.0) + v
    all_timings.update(matches.timings)
    all_timings.update(timings)
    all_timings["metrics"] = time.perf_counter() - t0
    all_timings["total"] = time.perf_counter() - t_start
    reporter.progress(1.0, "done")
    return RegistrationResult(
        T_target_source=T_world,
        T_coarse=world_transform(coarse.T_target_source, target, source),
        confidence=coarse.confidence,
        message=coarse.message,
        target=tgt,
        source=src,
        matches=matches,
        coarse=coarse,
        fine=fine,
        metrics_coarse=m_coarse,
        metrics_fine=m_fine,
        timings=all_timings,
        params=params,
        tree=tree,
        overlap=quality.overlap,
        strength=quality.strength,
        slices=quality.slices,
    )


def _stem_in(cloud: Cloud, xy: np.ndarray, role: str) -> np.ndarray:
    """Return a stem given in world x y in ``cloud``'s local frame.

    Raises InvalidInput when it is not two finite numbers within the scan's extent
    (and ``STEM_REACH_M`` around it).
    """
    at = np.asarray(xy, float).reshape(-1)
    if at.shape != (2,) or not np.isfinite(at).all():
        raise InvalidInput(f"The stem of {role} must be two finite numbers, x y.")
    local: np.ndarray = at - cloud.offset[:2]
    lo = cloud.xyz[:, :2].min(axis=0) - STEM_REACH_M
    hi = cloud.xyz[:, :2].max(axis=0) + STEM_REACH_M
    if not ((lo <= local) & (local <= hi)).all():
        wlo, whi = lo + cloud.offset[:2], hi + cloud.offset[:2]
        raise InvalidInput(
            f"The stem of {role} at ({at[0]:g}, {at[1]:g}) lies outside its points "
            f"(x {wlo[0]:.1f} to {whi[0]:.1f}, y {wlo[1]:.1f} to {whi[1]:.1f}): give "
            "it in the scan's own coordinates, as amrst info shows them."
        )
    return local
