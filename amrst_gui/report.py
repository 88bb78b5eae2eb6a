"""The registration report from the app: built from the session, written with Export.

The engine's :mod:`amrst.results.report_html` writes the page (the same file as ``amrst
register --report``); this module collects the session's state into its inputs and
runs the export and the report in one worker job. No widgets.
"""

from __future__ import annotations

import time
from typing import TYPE_CHECKING, Any

from amrst.results.report_html import REPORT_NAME, ReportInputs, report_page

if TYPE_CHECKING:
    from pathlib import Path

    from amrst.progress import Reporter
    from amrst_gui.session import Session


def report_inputs(session: Session) -> ReportInputs | None:
    """What the report shows of the session's current result; None without one."""
    T = session.final_transform
    coarse = session.accepted_coarse
    verdict = session.verdict
    target, source = session.cloud("target"), session.cloud("source")
    if T is None or coarse is None or verdict is None:
        return None
    if target is None or source is None:
        return None
    metrics: dict[str, dict[str, Any]] = {}
    truth: dict[str, dict[str, Any]] = {}
    for stage in ("coarse", "fine"):
        values = session.metrics_report().get(stage, {})
        metrics[stage] = {k: v for k, v in values.items() if not k.startswith("truth_")}
        found = {k[6:]: v for k, v in values.items() if k.startswith("truth_")}
        if found:
            truth[stage] = found
    if session.fine is None:
        metrics.pop("fine")
    paths = (session.path("target"), session.path("source"))
    quality = session.pose_quality
    return ReportInputs(
        target=target,
        source=source,
        target_file=str(paths[0] or target.name),
        source_file=str(paths[1] or source.name),
        T_local=T,
        stage="fine" if session.fine is not None else "coarse",
        verdict=verdict,
        candidates=tuple(session.matches),
        chosen_id=None if coarse.candidate is None else int(coarse.candidate.id),
        params=session.result_params,
        rejected_ids=session.rejected,
        metrics=metrics,
        truth=truth,
        tree=session.tree,
        timings=session.timings,
        override=session.export_override,
        manual_labels=session.manual_labels,
        notes=(session.fine_note,) if session.fine_note else (),
        quality=None if quality is None else quality.section(),
        strength=None if quality is None else dict(quality.strength.values),
    )


def export_with_report(
    out_dir: Path,
    kwargs: dict,
    inputs: ReportInputs | None,
    reporter: Reporter,
) -> tuple[list[Path], float]:
    """Write the chosen outputs and ``report.html`` as one set (a worker job)."""
    from amrst.files.atomic import text_writer
    from amrst_gui import jobs

    start = time.perf_counter()
    if inputs is not None:
        reporter.progress(0.0, "Drawing the report's pictures")
        kwargs = {
            **kwargs,
            "extra_files": {REPORT_NAME: text_writer(report_page(inputs))},
        }
        reporter.check_cancelled()
    paths, _seconds = jobs.export_pair(out_dir, kwargs, reporter)
    return paths, time.perf_counter() - start
