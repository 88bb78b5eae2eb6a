"""One link: two analysed scans matched, verified and ranked into candidate solutions.

:func:`find_matches` matches similar tetrahedra between the key points, verifies and
ranks every solution, then asks the other candidate sources (``sources.py``) to add
theirs into the same ranked list; :func:`coarse_from_matches` picks the best one the
user has not rejected. Transforms here are local: they map the source's local
coordinates into the target's (``amrst.types.world_transform`` converts).
"""

from __future__ import annotations

import logging
import time
from dataclasses import dataclass, field, replace
from typing import TYPE_CHECKING

import numpy as np

from amrst.errors import RegistrationFailed
from amrst.neighbours import THREADS
from amrst.pipeline.analysis import _timed
from amrst.pipeline.sources import CANDIDATE_SOURCES, merge_same_solutions
from amrst.progress import NULL_REPORTER, Reporter, SubReporter
from amrst.stages.coarse import CandidateList, choose_coarse, rank_candidates
from amrst.stages.match import TetraMatches, match_tetrahedra

if TYPE_CHECKING:
    from amrst.params import RegistrationParams
    from amrst.pipeline.analysis import ScanAnalysis
    from amrst.stages.coarse import Candidate, CoarseResult
    from amrst.stages.fine import FineResult

log = logging.getLogger(__name__)


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


def find_matches(
    target: ScanAnalysis,
    source: ScanAnalysis,
    params: RegistrationParams,
    reporter: Reporter = NULL_REPORTER,
    *,
    threads: int = THREADS,
) -> MatchResult:
    """Match tetrahedra between the two key point sets, then verify and rank them.

    ``threads``: for the KD-tree queries.
    """
    if target.keypoints is None or source.keypoints is None:
        raise RegistrationFailed(
            "Build the skeletons and key points of both scans first."
        )
    few = [
        f"The {name} skeleton has only {len(kp.xyz)} key points; 4 are needed for a "
        "tetrahedron."
        for name, kp in (("target", target.keypoints), ("source", source.keypoints))
        if len(kp.xyz) < 4
    ]
    trunk_available = params.trunk.mode != "off" and params.match.levelled
    if few and not trunk_available:
        raise RegistrationFailed(
            f"{few[0]} Raise the depth rule (max_depth), lower the pruning length, "
            "or skeletonise all points."
        )
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
        threads=threads,
    )
    t0 = _timed(timings, "verify", t0)
    centre = source.xyz.mean(axis=0)
    finished: dict[int, FineResult] = {}
    n = len(CANDIDATE_SOURCES)
    for k, extra in enumerate(CANDIDATE_SOURCES):
        if not extra.wanted(ranked, params, centre):
            continue
        step = SubReporter(
            reporter, 0.8 + 0.2 * k / n, 0.8 + 0.2 * (k + 1) / n, extra.label
        )
        ranked, fits = extra.add(ranked, target, source, params, step, threads)
        finished.update(fits)
        t0 = _timed(timings, extra.timing_key, t0)
    if len(ranked.candidates) > 1:
        ranked = merge_same_solutions(ranked, centre)
    return MatchResult(
        tetra, ranked.candidates, ranked.n_matches, timings, centre, finished
    )


def coarse_from_matches(
    matches: MatchResult, rejected: frozenset[int] = frozenset()
) -> CoarseResult:
    """Return the best candidate not rejected by the user (local frames)."""
    return choose_coarse(
        CandidateList(matches.candidates, matches.n_matches),
        rejected,
        matches.source_centre,
    )
