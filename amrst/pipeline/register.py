"""``register()``: the whole chain for one pair of scans, as the CLI runs it."""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np

from amrst.measure import TreeMeasures, measure_registration
from amrst.params import RegistrationParams
from amrst.pipeline.analysis import ScanAnalysis, analyse_scan, both_scans
from amrst.pipeline.link import MatchResult, coarse_from_matches, find_matches
from amrst.pipeline.refine import evaluate, refine
from amrst.progress import NULL_REPORTER, Reporter, SubReporter
from amrst.types import world_transform

if TYPE_CHECKING:
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
    # Height, DBH and crown of "target", "source" (moved) and "merged", full clouds.
    tree: dict[str, TreeMeasures] = field(default_factory=dict)


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
        return analyse_scan(cloud, params, rep)

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
