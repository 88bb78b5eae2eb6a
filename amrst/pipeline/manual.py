"""A registration from the technician's point pairs instead of the automatic match.

Both scans are analysed as usual; the pose fitted to the pairs becomes the one
candidate (origin ``manual``), verified like an automatic one, then refined by Fine.
Fine's result replaces the pairs' pose only when it stays the same solution and does
not lower the verification score: on scans that share little, ICP can slide to a
wrong pose the pairs ruled out.
"""

from __future__ import annotations

import dataclasses
import logging
import time
from typing import TYPE_CHECKING

import numpy as np

from amrst.errors import InvalidInput
from amrst.pipeline.analysis import analyse_scan, both_scans
from amrst.pipeline.link import MatchResult
from amrst.pipeline.refine import refine
from amrst.pipeline.register import finish_registration
from amrst.progress import NULL_REPORTER, SubReporter
from amrst.review.manual import (
    MANUAL_ID_BASE,
    fit_pairs,
    pairs_disagree,
    score_manual,
    weak_turn,
)
from amrst.review.manual_keep import keep_manual
from amrst.stages.candidates import CandidateList, choose_coarse
from amrst.stages.match import TetraMatches

if TYPE_CHECKING:
    from amrst.params import RegistrationParams
    from amrst.pipeline.analysis import ScanAnalysis
    from amrst.pipeline.register import RegistrationResult
    from amrst.progress import Reporter
    from amrst.types import Cloud

log = logging.getLogger(__name__)


def register_from_pairs(
    target: Cloud,
    source: Cloud,
    pairs: tuple[np.ndarray, np.ndarray],
    params: RegistrationParams,
    reporter: Reporter | None = None,
    *,
    levelled: bool = False,
) -> RegistrationResult:
    """Register ``source`` onto ``target`` from point pairs in world coordinates.

    Parameters
    ----------
    target, source : Cloud
    pairs : (target_pts, source_pts), each (K, 3) float64
        The same K points picked in both scans, world coordinates of each file.
    params : RegistrationParams
    reporter : Reporter or None
    levelled : bool
        Fit only a heading and a shift (scanners levelled in the field).

    Returns
    -------
    RegistrationResult
        As :func:`amrst.pipeline.register.register`; ``coarse`` is the pairs' pose.

    Raises
    ------
    InvalidInput
        Pairs that cannot fix a pose (fewer than 2, or all on one line).
    """
    reporter = reporter or NULL_REPORTER
    t_start = time.perf_counter()
    t_pts = np.asarray(pairs[0], float) - target.offset
    s_pts = np.asarray(pairs[1], float) - source.offset
    fit = fit_pairs(t_pts, s_pts, levelled=levelled)
    if not np.all(np.isfinite(fit.T_target_source)):
        raise InvalidInput(
            "The point pairs do not fix a pose: pick them farther apart."
        )
    if apart := pairs_disagree(t_pts, s_pts):
        raise InvalidInput(f"The point pairs {apart}.")
    if advice := weak_turn(t_pts):
        log.warning("%s", advice)

    def analyse(cloud: Cloud, rep: Reporter) -> ScanAnalysis:
        return analyse_scan(cloud, params, rep)

    tgt, src = both_scans(analyse, target, source, SubReporter(reporter, 0.0, 0.7))
    how = f"{len(t_pts)} point pairs, residual RMS {fit.rmse_m * 100:.1f} cm"
    cand = dataclasses.replace(
        score_manual(
            fit.T_target_source, tgt.xyz, src.xyz, params.coarse, MANUAL_ID_BASE, how
        ),
        rank=1,
    )
    matches = MatchResult(
        TetraMatches.empty(), (cand,), 0, source_centre=src.xyz.mean(axis=0)
    )
    coarse = choose_coarse(
        CandidateList((cand,), 0), frozenset(), matches.source_centre
    )
    t0 = time.perf_counter()
    fine = refine(tgt, src, coarse, params, SubReporter(reporter, 0.7, 0.9, "fine"))
    fine, _ = keep_manual(fine, coarse.T_target_source, tgt.xyz, src.xyz, params.coarse)
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
    )
