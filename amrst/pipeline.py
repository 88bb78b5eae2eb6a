"""The AMRST chain, stage by stage, as the CLI, the app and the benchmark run it.

register(target, source) reads like the method:
  1. preprocess each scan (outliers, thinning)         stages/preprocess.py
  2. separate wood and leaves                          stages/separate.py
  3. skeletonise the wood, 4. pick key points          stages/skeleton.py, keypoints.py
  5. match similar tetrahedra between the key points   stages/match.py
  6. verify and rank every match; coarse solution      stages/coarse.py
  7. refine with ICP (LM-ICP or robust point-to-plane)  stages/fine.py
  8. measure (NN-RMSE, Hausdorff, overlap)             stages/metrics.py
The app calls the same steps one at a time (prepare_scan, skeletonise_scan, find_matches,
coarse_from_matches, refine, evaluate) so the user can look and overrule between them.
Engine stages work in each cloud's local coordinates; the transforms returned by
register() and used by export are in world coordinates (see amrst.types.world_transform).
"""

from __future__ import annotations

import logging
import time
from dataclasses import dataclass, field, replace
from typing import TYPE_CHECKING, TypeVar

import numpy as np

from amrst.errors import Cancelled, InvalidInput, RegistrationFailed
from amrst.measure import TreeMeasures, measure_registration
from amrst.params import RegistrationParams
from amrst.progress import NULL_REPORTER, Reporter, SharedReporter, SubReporter
from amrst.stages.coarse import (
    CandidateList,
    CoarseResult,
    choose_coarse,
    rank_candidates,
)
from amrst.stages.fine import FineResult, refine_registration
from amrst.stages.keypoints import KeypointResult, extract_keypoints
from amrst.stages.match import TetraMatches, match_tetrahedra
from amrst.stages.metrics import CloudMetrics, measure_clouds
from amrst.stages.preprocess import (
    PreprocessResult,
    preprocess_points,
)
from amrst.stages.separate import SeparationResult, separate_wood
from amrst.stages.skeleton import SkeletonResult, build_skeleton
from amrst.stages.trunk import (
    merge_trunk_solutions,
    score_transforms,
    search_yaw,
    trunk_contenders,
)
from amrst.types import Cloud, Transform, world_transform

if TYPE_CHECKING:
    from collections.abc import Callable

    from scipy.spatial import cKDTree

    from amrst.stages.coarse import Candidate

_Item = TypeVar("_Item")
_Out = TypeVar("_Out")

log = logging.getLogger(__name__)


@dataclass(frozen=True, slots=True)
class ScanAnalysis:
    """One scan after the per-scan stages; later fields are None until computed."""

    cloud: Cloud
    pre: PreprocessResult
    separation: SeparationResult
    skeleton: SkeletonResult | None = None
    keypoints: KeypointResult | None = None
    timings: dict[str, float] = field(default_factory=dict)

    @property
    def xyz(self) -> np.ndarray:
        """(N, 3) preprocessed points, local coordinates."""
        return self.pre.xyz

    @property
    def is_wood(self) -> np.ndarray:
        """(N,) bool wood label of the preprocessed points."""
        return self.separation.is_wood

    def points(self, which: str) -> np.ndarray:
        """Preprocessed points: 'all', 'wood' or 'leaf' (falls back to all when too few)."""
        if which == "all":
            return self.xyz
        sel = self.xyz[self.is_wood if which == "wood" else ~self.is_wood]
        return sel if len(sel) >= 100 else self.xyz


@dataclass(frozen=True, slots=True)
class MatchResult:
    """Tetrahedron matches and the ranked candidate solutions built from them."""

    tetra: TetraMatches
    candidates: tuple[Candidate, ...]  # best first
    n_matches: int
    timings: dict[str, float] = field(default_factory=dict)
    source_centre: np.ndarray = field(
        default_factory=lambda: np.zeros(3)
    )  # (3,) source centroid
    # candidate id -> FineResult already computed while verifying it (trunk search)
    refined: dict[int, FineResult] = field(default_factory=dict)


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
    # Height, DBH and crown of "target", "source" (moved) and "merged", full clouds.
    tree: dict[str, TreeMeasures] = field(default_factory=dict)


def _timed(timings: dict[str, float], key: str, t0: float) -> float:
    now = time.perf_counter()
    timings[key] = timings.get(key, 0.0) + now - t0
    return now


def prepare_scan(
    cloud: Cloud, params: RegistrationParams, reporter: Reporter = NULL_REPORTER
) -> ScanAnalysis:
    """Preprocess one scan and separate wood from leaves."""
    timings: dict[str, float] = {}
    t0 = time.perf_counter()
    try:
        pre = preprocess_points(
            cloud.xyz, params.preprocess, SubReporter(reporter, 0, 0.3, "preprocess")
        )
    except InvalidInput as exc:  # say which scan
        raise InvalidInput(f"{cloud.name or 'scan'}: {exc}") from exc
    t0 = _timed(timings, "preprocess", t0)
    intensity = cloud.intensity
    sep = separate_wood(
        pre.xyz,
        None if intensity is None else intensity[pre.index],
        params.separate,
        SubReporter(reporter, 0.3, 1.0, "wood-leaf separation"),
    )
    _timed(timings, "separate", t0)
    return ScanAnalysis(cloud, pre, sep, timings=timings)


def skeletonise_scan(
    analysis: ScanAnalysis,
    params: RegistrationParams,
    reporter: Reporter = NULL_REPORTER,
) -> ScanAnalysis:
    """Add the skeleton and the key points to a prepared scan."""
    timings = dict(analysis.timings)
    t0 = time.perf_counter()
    pts = analysis.points(params.skeleton.points)
    if len(pts) < params.skeleton.min_points:
        pts = analysis.xyz
    skel = build_skeleton(
        pts, params.skeleton, SubReporter(reporter, 0, 0.9, "skeleton")
    )
    t0 = _timed(timings, "skeleton", t0)
    kp = extract_keypoints(skel, params.keypoints)
    _timed(timings, "keypoints", t0)
    reporter.progress(1.0, f"{len(kp.xyz)} key points")
    return replace(analysis, skeleton=skel, keypoints=kp, timings=timings)


def find_matches(
    target: ScanAnalysis,
    source: ScanAnalysis,
    params: RegistrationParams,
    reporter: Reporter = NULL_REPORTER,
) -> MatchResult:
    """Match tetrahedra between the two key point sets, then verify and rank them."""
    if target.keypoints is None or source.keypoints is None:
        raise RegistrationFailed(
            "Build the skeletons and key points of both scans first."
        )
    few = [
        f"The {name} skeleton has only {len(kp.xyz)} key points; 4 are needed for a "
        "tetrahedron. Raise the depth rule (max_depth), lower the pruning length, or skeletonise all points."
        for name, kp in (("target", target.keypoints), ("source", source.keypoints))
        if len(kp.xyz) < 4
    ]
    trunk_available = params.trunk.mode != "off" and params.match.levelled
    if few and not trunk_available:
        raise RegistrationFailed(few[0])
    timings: dict[str, float] = {}
    t0 = time.perf_counter()
    if few:
        # No tetrahedron to match: the trunk heading search may still register them.
        log.warning("%s Trying the trunk heading search alone.", few[0])
        tetra = TetraMatches.empty()
    else:
        tetra = match_tetrahedra(
            target.keypoints.xyz,
            source.keypoints.xyz,
            params.match,
            SubReporter(reporter, 0, 0.4, "matching"),
        )
    if len(tetra.T_target_source) == 0 and params.match.retry_relaxed and not few:
        # One retry with looser tolerances before giving up (said in the log).
        m = params.match
        relaxed = replace(
            m,
            edge_tolerance=min(2 * m.edge_tolerance, 0.3),
            max_residual_m=1.5 * m.max_residual_m,
            height_tolerance_m=1.5 * m.height_tolerance_m,
            volume_tolerance=min(2 * m.volume_tolerance, 1.0),
        )
        log.info(
            "No congruent tetrahedra; retrying with edge tolerance %.2f, residual %.2f m",
            relaxed.edge_tolerance,
            relaxed.max_residual_m,
        )
        tetra = match_tetrahedra(
            target.keypoints.xyz,
            source.keypoints.xyz,
            relaxed,
            SubReporter(reporter, 0, 0.4, "matching (relaxed)"),
        )
    t0 = _timed(timings, "match", t0)
    ranked: CandidateList = rank_candidates(
        tetra,
        target.xyz,
        source.xyz,
        params.coarse,
        SubReporter(reporter, 0.4, 0.8, "verification"),
    )
    t0 = _timed(timings, "verify", t0)
    centre = source.xyz.mean(axis=0)
    finished: dict[int, FineResult] = {}
    if _wants_trunk_search(ranked, params, centre):
        ranked, finished = _add_trunk_solutions(
            ranked, target, source, params, SubReporter(reporter, 0.8, 1.0, "trunk")
        )
        _timed(timings, "trunk", t0)
    return MatchResult(
        tetra, ranked.candidates, ranked.n_matches, timings, centre, finished
    )


def _wants_trunk_search(
    ranked: CandidateList, params: RegistrationParams, centre: np.ndarray
) -> bool:
    mode = params.trunk.mode
    if mode == "off" or not params.match.levelled:
        return False
    if mode == "always" or not ranked.candidates:
        return True
    return not choose_coarse(ranked, frozenset(), centre).verified


def _add_trunk_solutions(
    ranked: CandidateList,
    target: ScanAnalysis,
    source: ScanAnalysis,
    params: RegistrationParams,
    reporter: Reporter,
) -> tuple[CandidateList, dict[int, FineResult]]:
    """Run the trunk heading search, refine its best headings, add them to the list.

    Returns the merged list and ``{candidate id: FineResult}`` for the solutions that
    already had their full fine registration.
    """
    from scipy.spatial import cKDTree

    tree = cKDTree(target.xyz)  # one tree for the sweep and every score below
    search = search_yaw(
        target.xyz,
        source.xyz,
        params.trunk,
        SubReporter(reporter, 0, 0.6, "search"),
        target_tree=tree,
    )
    log.info("Trunk heading search kept %d heading(s)", len(search.solutions))
    # Rank the kept headings by a quick fine registration, then refine the best one
    # and its close contenders with the full settings (the rest stay as the quick
    # pass left them).
    choice = params.trunk.fine_points
    tries = ("all", "leaf") if choice == "best" else (choice,)
    quick = replace(
        params,
        fine=replace(
            params.fine,
            points=tries[0],
            voxel_size_m=params.trunk.refine_voxel_m,
            max_iterations=params.trunk.refine_iterations,
        ),
    )
    refined, used = [], []
    n = len(search.solutions)
    for k, sol in enumerate(search.solutions):
        step = SubReporter(reporter, 0.6 + 0.3 * k / n, 0.6 + 0.3 * (k + 1) / n)
        refined.append(
            refine(target, source, sol.T_target_source, quick, step).T_target_source
        )
        used.append(tries[0])
        step.progress(1.0, "refining the best headings")
    done: list[FineResult] = []
    if refined:
        # The best quick fit, and every heading whose quick fit comes close to it,
        # gets the full fine registration (on each point set tried); then the
        # close-point share decides. A quick fit that stopped short must not settle
        # a close race (case 17 flipped on the fine stage's sample size).
        close = _precise(refined, tree, source, params)
        contenders = trunk_contenders(
            close, params.trunk.contender_share, refined, source.xyz.mean(axis=0)
        )
        runs = [(k, points) for k in contenders for points in tries]
        fits = []
        for i, (k, points) in enumerate(runs):
            fits.append(
                refine(
                    target,
                    source,
                    refined[k],
                    replace(params, fine=replace(params.fine, points=points)),
                    SubReporter(
                        reporter,
                        0.9 + 0.1 * i / len(runs),
                        0.9 + 0.1 * (i + 1) / len(runs),
                    ),
                )
            )
        scores = _precise([f.T_target_source for f in fits], tree, source, params)
        for j, k in enumerate(contenders):  # runs hold each contender's tries in turn
            pick = max(
                range(j * len(tries), (j + 1) * len(tries)), key=scores.__getitem__
            )
            refined[k], used[k] = fits[pick].T_target_source, runs[pick][1]
            done.append(fits[pick])
    merged = merge_trunk_solutions(
        ranked,
        search,
        refined,
        tree,
        source.xyz,
        params.coarse,
        params.trunk.score_dist_m,
        used,
    )
    # These headings already had their full fine registration: register() reuses it.
    finished = {
        c.id: fit
        for fit in done
        for c in merged.candidates
        if c.T_target_source is fit.T_target_source
    }
    return merged, finished


def _precise(
    transforms: list[Transform],
    target_tree: cKDTree,
    source: ScanAnalysis,
    params: RegistrationParams,
) -> np.ndarray:
    """Share of sampled source points within trunk.score_dist_m under each transform."""
    return score_transforms(
        transforms, target_tree, source.xyz, params.coarse, params.trunk.score_dist_m
    )[1]


def coarse_from_matches(
    matches: MatchResult, rejected: frozenset[int] = frozenset()
) -> CoarseResult:
    """Return the best candidate not rejected by the user (local frames)."""
    return choose_coarse(
        CandidateList(matches.candidates, matches.n_matches),
        rejected,
        matches.source_centre,
    )


def refine(
    target: ScanAnalysis,
    source: ScanAnalysis,
    start: Transform | CoarseResult,
    params: RegistrationParams,
    reporter: Reporter = NULL_REPORTER,
    matches: MatchResult | None = None,
) -> FineResult:
    """Fine registration from a coarse local-frame transform or an accepted coarse result.

    A coarse result from the trunk heading search is refined on the point set its
    verification chose (``Candidate.fine_points``); anything else on ``fine.points``.
    When ``matches`` already holds this candidate's full fine registration (the trunk
    search makes one while verifying), that result is returned instead of a second run.
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
        source.points(which), target.points(which), T_init, params.fine, reporter
    )


def evaluate(
    target: ScanAnalysis,
    source: ScanAnalysis,
    T_target_source: Transform,
    params: RegistrationParams,
) -> CloudMetrics:
    """NN-RMSE, Hausdorff and overlap of the preprocessed scans under a local-frame transform."""
    moved = source.xyz @ T_target_source[:3, :3].T + T_target_source[:3, 3]
    return measure_clouds(target.xyz, moved, params.metrics)


def both_scans(
    fn: Callable[[_Item, Reporter], _Out],
    target_item: _Item,
    source_item: _Item,
    reporter: Reporter = NULL_REPORTER,
) -> tuple[_Out, _Out]:
    """Run ``fn(item, reporter)`` for the target's and the source's item at once.

    One thread each; returns ``(target result, source result)``.

    The per-scan stages' KD-tree queries and large numpy steps release the GIL, which
    made them 1.24-1.37x faster on this 2-core machine; results are the same as one
    after the other. Progress is the mean of the two (monotonic). When one task fails
    (or the caller is interrupted) the other stops at its next cancel check instead
    of running to the end; the error is raised as the serial order would have raised
    it (the target's first).
    """
    from concurrent.futures import ThreadPoolExecutor

    shared = SharedReporter(reporter, 2)
    with ThreadPoolExecutor(max_workers=2, thread_name_prefix="amrst-scan") as pool:
        jobs = [
            pool.submit(_stop_sibling_on_error, fn, item, shared.task(i, role), shared)
            for i, (item, role) in enumerate(
                ((target_item, "target"), (source_item, "source"))
            )
        ]
        try:
            results = [job.result() for job in jobs]
        except BaseException:
            shared.stop()
            for job in jobs:  # the real error over the Cancelled it caused
                if job.done() and not job.cancelled():
                    exc = job.exception()
                    if exc is not None and not isinstance(exc, Cancelled):
                        raise exc from None
            raise
    return results[0], results[1]


def _stop_sibling_on_error(
    fn: Callable[[_Item, Reporter], _Out],
    item: _Item,
    rep: Reporter,
    shared: SharedReporter,
) -> _Out:
    try:
        return fn(item, rep)
    except BaseException:
        shared.stop()
        raise


def register(
    target: Cloud,
    source: Cloud,
    params: RegistrationParams | None = None,
    reporter: Reporter | None = None,
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

    def analyse(cloud: Cloud, rep: Reporter) -> ScanAnalysis:
        an = prepare_scan(cloud, params, SubReporter(rep, 0.0, 0.7))
        return skeletonise_scan(an, params, SubReporter(rep, 0.7, 1.0))

    tgt, src = both_scans(analyse, target, source, SubReporter(reporter, 0.0, 0.6))
    matches = find_matches(tgt, src, params, SubReporter(reporter, 0.6, 0.85, ""))
    coarse = coarse_from_matches(matches)
    t0 = time.perf_counter()
    fine = refine(
        tgt,
        src,
        coarse,
        params,
        SubReporter(reporter, 0.85, 0.95, "fine"),
        matches,
    )
    t_fine = time.perf_counter() - t0
    t0 = time.perf_counter()
    m_coarse = evaluate(tgt, src, coarse.T_target_source, params)
    # A trunk-search solution was fine-registered while it was verified: its coarse
    # and fine transforms are the same, and so are their metrics.
    same = np.array_equal(fine.T_target_source, coarse.T_target_source)
    m_fine = m_coarse if same else evaluate(tgt, src, fine.T_target_source, params)
    T_world = world_transform(fine.T_target_source, target, source)
    tree = measure_registration(target, source, T_world, params.measure)
    timings: dict[str, float] = {}
    for an in (tgt, src):
        for k, v in an.timings.items():
            timings[k] = timings.get(k, 0.0) + v
    timings.update(matches.timings)
    timings["fine"] = t_fine
    timings["metrics"] = time.perf_counter() - t0
    timings["total"] = time.perf_counter() - t_start
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
        timings=timings,
        params=params,
        tree=tree,
    )
