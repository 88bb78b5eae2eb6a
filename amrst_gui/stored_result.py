"""A stored link result as the app's result objects (no Qt, no session).

A campaign tree, or a link of a plot, opens without registering: the Session reads
the link's two scans and then puts :func:`stored_results` in place of the computed
steps: one candidate (the stored pose), the accepted coarse result and the fine
result at that pose, the stored metrics, tree measures, parameters and verdict.
Match, Accept coarse and Fine then read as done, so the overlay shows the stored pose
at once and no step runs.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np

if TYPE_CHECKING:
    from amrst.campaign.stored import StoredLinkResult
    from amrst.measure import TreeMeasures
    from amrst.params import RegistrationParams
    from amrst.pipeline import MatchResult
    from amrst.pipeline.refine import PoseQuality
    from amrst.stages.candidates import CoarseResult
    from amrst.stages.fine import FineResult
    from amrst.stages.metrics import CloudMetrics

log = logging.getLogger("amrst_gui.session")

#: The id of the stored pose among the candidates (no match produces negative ids).
STORED_ID = -1
STORED_METHOD = "stored by the campaign batch or the plot"


@dataclass(frozen=True)
class StoredResults:
    """A stored link result as the results of the steps that made it."""

    params: RegistrationParams
    matches: MatchResult  # the stored pose, the one candidate
    coarse: CoarseResult
    fine: FineResult
    metrics: dict[str, CloudMetrics]
    tree: dict[str, TreeMeasures]
    truth: np.ndarray | None
    quality: PoseQuality | None  # the stored figures; no stem slices (no points)


def stored_params(
    stored: StoredLinkResult, current: RegistrationParams
) -> RegistrationParams:
    """The parameters the stored result was computed with (``current`` when it
    has none that can be read)."""
    from amrst.errors import AmrstError
    from amrst.params import params_from_dict

    if not stored.params:
        return current
    try:
        return params_from_dict(stored.params)
    except AmrstError as exc:  # keep the current parameters
        log.warning("%s: its params.json is not used: %s", stored.label, exc)
        return current


def stored_results(
    stored: StoredLinkResult,
    params: RegistrationParams,
    T_local: np.ndarray,
    source_centre: np.ndarray,
) -> StoredResults:
    """The stored result at ``T_local`` (its pose between the scans' local frames),
    with ``source_centre`` as the candidates' centre (``same_solution``)."""
    from amrst.pipeline import MatchResult
    from amrst.stages.candidates import Candidate, CoarseResult, Origin
    from amrst.stages.fine import FineResult
    from amrst.stages.match import TetraMatches

    T = T_local
    try:
        origin = Origin(stored.origin)
    except ValueError:
        origin = Origin.TETRAHEDRA
    score = 0.0 if math.isnan(stored.score) else float(stored.score)
    candidate = Candidate(
        id=STORED_ID,
        rank=1,
        score=score,
        raw_score=score,
        support=0,
        volume_m3=math.nan,
        edge_error=math.nan,
        svd_residual_m=math.nan,
        target_idx=np.zeros(4, np.int64),
        source_idx=np.zeros(4, np.int64),
        T_match=T,
        T_target_source=T,
        polished=True,
        explanation=f"Stored result: {stored.label}",
        origin=origin,
    )
    matches = MatchResult(
        TetraMatches.empty(), (candidate,), 0, {}, np.asarray(source_centre)
    )
    confidence = 0.0 if math.isnan(stored.confidence) else stored.confidence
    coarse = CoarseResult(
        candidate,
        T,
        confidence,
        0.0,
        str(stored.verdict.get("reason", "")),
        stored.verified,
    )
    # A pair tree's metrics.json keeps what its ICP reported; a link of more
    # scans has the joint refinement's pose, no ICP of its own.
    icp = stored.metrics_fine or {}
    fine = FineResult(
        T,
        f"{icp['method']} ({STORED_METHOD})" if "method" in icp else STORED_METHOD,
        bool(icp.get("converged", True)),
        int(icp.get("iterations", 0)),
        float(icp.get("fitness", math.nan)),
        float(icp.get("inlier_rmse_m", math.nan)),
        math.nan,
    )
    metrics = {
        stage: m
        for stage, values in (
            ("coarse", stored.metrics_coarse),
            ("fine", stored.metrics_fine),
        )
        if (m := cloud_metrics(values)) is not None
    }
    tree = {
        name: m
        for name, d in stored.tree.items()
        if (m := tree_measures(d)) is not None
    }
    truth = None if stored.T_truth is None else np.asarray(stored.T_truth, float)
    quality = pose_quality(stored.quality, stored.strength)
    return StoredResults(params, matches, coarse, fine, metrics, tree, truth, quality)


def pose_quality(
    quality: dict[str, Any] | None, strength: dict[str, Any] | None
) -> PoseQuality | None:
    """PoseQuality from metrics.json's ``quality`` and ``strength`` sections.

    None when the distances are missing; the stem slices are not stored as points,
    so the Stem slices tab makes its own.
    """
    from amrst.pipeline.refine import PoseQuality
    from amrst.review.overlap import OverlapDistances
    from amrst.review.strength import AXES, Strength

    d = (quality or {}).get("distance")
    if not isinstance(d, dict):
        return None

    def num(value: Any) -> float:
        # null (NaN in metrics.json) or anything not a number reads as unknown
        ok = isinstance(value, (int, float)) and not isinstance(value, bool)
        return float(value) if ok else math.nan

    # Files of older versions call the count n_points.
    n = num(d.get("n_points_measured", d.get("n_points")))
    overlap = OverlapDistances(
        median_m=num(d.get("median_m")),
        p95_m=num(d.get("p95_m")),
        within_2cm_fraction=num(d.get("within_2cm_fraction")),
        overlap_fraction=num(d.get("overlap_fraction")),
        n_points_measured=int(n) if math.isfinite(n) else 0,
    )
    values = {axis: num((strength or {}).get(axis)) for axis in AXES}
    return PoseQuality(overlap, Strength(values, 0), ())


def cloud_metrics(values: dict[str, Any] | None) -> Any:
    """CloudMetrics from their dict form (None when it is not one)."""
    from dataclasses import fields

    from amrst.stages.metrics import CloudMetrics

    if not values:
        return None
    names = [f.name for f in fields(CloudMetrics)]
    if any(n not in values for n in names):
        return None
    return CloudMetrics(**{n: values[n] for n in names})


def tree_measures(d: dict[str, Any]) -> TreeMeasures | None:
    """TreeMeasures from their ``as_dict`` form (None when it is not one)."""
    from amrst.measure import TreeMeasures
    from amrst.measure.stem import StemCircle

    def num(key: str) -> float:
        value = d.get(key)
        return math.nan if value is None else float(value)

    if "height_m" not in d:
        return None
    stem = None
    if d.get("stem_x_m") is not None and not math.isnan(num("dbh_m")):
        stem = StemCircle(
            centre_xy=(num("stem_x_m"), num("stem_y_m")),
            radius_m=num("dbh_m") / 2,
            rmse_m=num("stem_rmse_m"),
            n_points=int(d.get("stem_points") or 0),
            arc_deg=num("stem_arc_deg"),
        )
    return TreeMeasures(
        n_points=int(d.get("n_points") or 0),
        base_z=num("base_z_m"),
        height_m=num("height_m"),
        dbh_m=num("dbh_m"),
        stem=stem,
        crown_area_m2=num("crown_area_m2"),
        crown_width_m=num("crown_width_m"),
        note=str(d.get("note", "")),
        dbh_doubt=str(d.get("dbh_doubt", "")),
    )
