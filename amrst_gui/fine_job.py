"""Fine registration as a worker job that never silently drops a better manual pose.

From a manual candidate, Fine's result replaces the technician's pose only when it
stays the same solution and does not lower the verification score
(:func:`amrst.review.manual_keep.judge_refinement`); otherwise the manual pose is the fine
result, and the decision says why. No widgets.
"""

from __future__ import annotations

import dataclasses
import time
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from amrst.pipeline.refine import PoseQuality
    from amrst.progress import Reporter
    from amrst.review.manual_keep import KeepDecision


def refine_keeping_manual(
    analyses: dict, coarse: Any, params: Any, reporter: Reporter, matches: Any = None
) -> tuple[tuple[Any, Any, dict, PoseQuality, KeepDecision | None], float]:
    """``jobs.refine_pair``, then the manual-pose check; adds the decision (or None):
    ``((fine, metrics, tree, PoseQuality, decision), seconds)``."""
    from amrst import pipeline
    from amrst.review.manual_keep import judge_refinement
    from amrst.stages.candidates import Origin
    from amrst_gui import jobs

    start = time.perf_counter()
    (fine, metrics, tree, quality), _s = jobs.refine_pair(
        analyses, coarse, params, reporter, matches=matches
    )
    cand = coarse.candidate
    if cand is None or cand.origin != Origin.MANUAL:
        return (fine, metrics, tree, quality, None), time.perf_counter() - start
    target, source = analyses["target"], analyses["source"]
    decision = judge_refinement(
        coarse.T_target_source,
        fine.T_target_source,
        target.xyz,
        source.xyz,
        params.coarse,
    )
    if decision.keep_manual:
        fine = dataclasses.replace(
            fine,
            T_target_source=coarse.T_target_source,
            method=f"{fine.method} (result dropped: manual pose kept)",
        )
        metrics = pipeline.evaluate(
            target, source, fine.T_target_source, params, threads=jobs.THREADS
        )
        tree = jobs.measure_tree_pair(analyses, fine.T_target_source, params, reporter)
        quality = jobs.pose_quality(analyses, fine.T_target_source, params)
    return (fine, metrics, tree, quality, decision), time.perf_counter() - start
