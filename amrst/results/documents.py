"""The result documents: transform.json, metrics.json and metrics.csv, built in one place.

The CLI and the app both fill a :class:`ResultRecord` and call
:func:`result_documents`, so they write the same keys; the export writes what it
returns. The documents carry
``schema_version`` (2); :func:`upgrade_result` reads the files written before (no
``schema_version``, by the CLI or by the app) into the current layout.
"""

from __future__ import annotations

import csv
import datetime as _dt
import io as _stdio
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, cast

import numpy as np

from amrst.measure import dbh_check
from amrst.stages.metrics import truth_errors

if TYPE_CHECKING:
    from collections.abc import Mapping

    from amrst.measure import TreeMeasures
    from amrst.pipeline import RegistrationResult
    from amrst.stages.coarse import CoarseResult
    from amrst.stages.fine import FineResult
    from amrst.stages.keypoints import KeypointResult
    from amrst.stages.metrics import TruthErrors
    from amrst.types import Transform

RESULT_SCHEMA_VERSION = 2
CONVENTION = "x_target = T_target_source @ [x_source, 1]; row-major, metres"


@dataclass(frozen=True, kw_only=True)
class ResultRecord:
    """What a result document holds, however the registration was run.

    ``metrics_coarse``/``metrics_fine`` are ``CloudMetrics.as_dict()``; ``truth`` maps a
    stage ("coarse", "fine") to its errors against a known transform; ``counts`` holds
    what only a whole run knows (key points, matches, candidates, wood fractions).
    """

    T_target_source: Transform  # (4, 4) world frame
    T_coarse: Transform | None = None
    target_name: str = ""
    source_name: str = ""
    target_file: str = ""
    source_file: str = ""
    coarse: CoarseResult | None = None
    fine: FineResult | None = None
    metrics_coarse: Mapping[str, Any] | None = None
    metrics_fine: Mapping[str, Any] | None = None
    truth: Mapping[str, TruthErrors] = field(default_factory=dict)
    tree: Mapping[str, TreeMeasures] = field(default_factory=dict)
    timings_s: Mapping[str, float] = field(default_factory=dict)
    rejected_match_ids: tuple[int, ...] = ()
    confidence: float | None = None  # overall; the coarse confidence when None
    message: str = ""
    counts: Mapping[str, Any] = field(default_factory=dict)
    amrst_version: str = ""
    # registered / needs review / failed, with reason and next step (amrst.review.verdict),
    # and whether the user chose to export a result that is not registered.
    verdict: Mapping[str, Any] | None = None
    # Set when the user exported a result that is not "registered" (the app asks):
    # what they overrode and when.
    override: Mapping[str, Any] | None = None
    # More context for transform.json (e.g. how a manual pose was given).
    extra: Mapping[str, Any] = field(default_factory=dict)
    # What the technician judges by (quality_section): distances where both scans
    # saw the scene and the stem slices; and the pose's strength per axis.
    quality: Mapping[str, Any] | None = None
    strength: Mapping[str, float] | None = None


@dataclass(frozen=True)
class ResultDocuments:
    """The content of transform.json, transform.txt, metrics.json and metrics.csv."""

    transform: dict[str, Any]
    transform_txt: str
    metrics: dict[str, Any]
    metrics_csv: str


def _candidate(coarse: CoarseResult | None) -> dict[str, Any] | None:
    c = None if coarse is None else coarse.candidate
    if c is None:
        return None
    return {
        "rank": int(c.rank),
        "id": int(c.id),
        "origin": str(c.origin),
        # Every source that proposed this pose (one candidate may name both).
        "found_by": [str(o) for o in c.origins],
        "explanation": str(c.explanation),
        "verification_score": float(c.score),
    }


def result_documents(record: ResultRecord) -> ResultDocuments:
    """Build the four result files of a registration from ``record``.

    Parameters
    ----------
    record : ResultRecord

    Returns
    -------
    ResultDocuments
        Plain, JSON-ready dicts (non-finite numbers are made ``null`` by the writer).
    """
    coarse, fine = record.coarse, record.fine
    verified = bool(coarse.verified) if coarse is not None else False
    confidence = record.confidence
    if confidence is None and coarse is not None:
        confidence = float(coarse.confidence)
    timings = {k: round(float(v), 4) for k, v in record.timings_s.items()}
    transform: dict[str, Any] = {
        "schema_version": RESULT_SCHEMA_VERSION,
        "T_target_source": np.asarray(record.T_target_source, float).tolist(),
        "T_coarse": None
        if record.T_coarse is None
        else np.asarray(record.T_coarse, float).tolist(),
        "convention": CONVENTION,
        "created": _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="seconds"),
        "amrst_version": record.amrst_version,
        "target": record.target_name,
        "source": record.source_name,
        "target_file": record.target_file,
        "source_file": record.source_file,
        "stage": "fine" if fine is not None else "coarse",
        "verified": verified,
        "verdict": None if record.verdict is None else dict(record.verdict),
        "exported_despite_verdict": record.override is not None,
        "override": None if record.override is None else dict(record.override),
        "confidence": confidence,
        "message": record.message,
        "coarse_candidate": _candidate(coarse),
        "fine": None
        if fine is None
        else {"method": str(fine.method), "converged": bool(fine.converged)},
        "rejected_match_ids": sorted(int(i) for i in record.rejected_match_ids),
        "timings_s": timings,
    }
    transform.update({k: v for k, v in record.extra.items() if k not in transform})
    metrics = _metrics(record, transform, verified)
    metrics["timings_s"] = timings
    text = (
        "\n".join(
            " ".join(f"{v:.12g}" for v in row)
            for row in np.asarray(record.T_target_source, float)
        )
        + "\n"
    )
    return ResultDocuments(transform, text, metrics, metrics_csv(metrics))


def _metrics(
    record: ResultRecord, transform: Mapping[str, Any], verified: bool
) -> dict[str, Any]:
    """metrics.json but its timings: verdict, both poses' metrics, tree, quality."""
    coarse, fine = record.coarse, record.fine
    metrics: dict[str, Any] = {"schema_version": RESULT_SCHEMA_VERSION}
    if record.verdict is not None:
        metrics["verdict"] = dict(record.verdict)
        metrics["exported_despite_verdict"] = record.override is not None
        if record.override is not None:
            metrics["override"] = dict(record.override)
    if record.metrics_coarse is not None or coarse is not None:
        section = dict(record.metrics_coarse or {})
        if coarse is not None:
            cand = _candidate(coarse) or {}
            section.update(
                candidate_rank=cand.get("rank"),
                candidate_id=cand.get("id"),
                candidate_origin=cand.get("origin"),
                verification_score=cand.get("verification_score"),
                confidence=float(coarse.confidence),
                verified=verified,
            )
        section["rejected_ids"] = transform["rejected_match_ids"]
        metrics["coarse"] = section
    if record.metrics_fine is not None or fine is not None:
        section = dict(record.metrics_fine or {})
        if fine is not None:
            section.update(
                method=str(fine.method),
                converged=bool(fine.converged),
                iterations=int(fine.iterations),
                fitness=float(fine.fitness),
                inlier_rmse_m=float(fine.inlier_rmse_m),
            )
        metrics["fine"] = section
    metrics.update(record.counts)
    _add_judgement(metrics, record)
    return metrics


def _add_judgement(metrics: dict[str, Any], record: ResultRecord) -> None:
    """Add what a technician judges by: the tree, quality, strength, truth errors."""
    if record.tree:
        # Height, DBH and crown of each scan alone and of the merged tree.
        metrics["tree"] = {name: m.as_dict() for name, m in record.tree.items()}
        if "merged" in record.tree:
            metrics["tree"]["merged"]["dbh_check"] = dbh_check(record.tree) or "ok"
    if record.quality is not None:
        metrics["quality"] = dict(record.quality)
    if record.strength is not None:
        metrics["strength"] = dict(record.strength)
    if record.truth:
        metrics["truth"] = {k: e.as_dict() for k, e in record.truth.items()}
        final = record.truth.get("fine") or record.truth.get("coarse")
        metrics["truth"]["registered"] = bool(final is not None and final.registered())


def _flatten(prefix: str, value: Any, out: dict[str, Any]) -> None:
    if isinstance(value, dict):
        for k, v in value.items():
            _flatten(f"{prefix}.{k}" if prefix else str(k), v, out)
    else:
        out[prefix] = value


def metrics_csv(metrics: Mapping[str, Any]) -> str:
    """Return the metrics as ``metric,value`` CSV rows (nested keys joined by dots)."""
    flat: dict[str, Any] = {}
    _flatten("", dict(metrics), flat)
    buf = _stdio.StringIO()
    w = csv.writer(buf)
    w.writerow(["metric", "value"])
    w.writerows(flat.items())
    return buf.getvalue()


def quality_section(result: RegistrationResult) -> dict[str, Any] | None:
    """Build the ``quality`` section of metrics.json: overlap distances, stem slices."""
    from amrst.pipeline.refine import PoseQuality

    if result.overlap is None or result.strength is None:
        return None
    return PoseQuality(result.overlap, result.strength, result.slices).section()


def record_from_registration(
    result: RegistrationResult,
    T_truth: Transform | None = None,
    **context: Any,
) -> ResultRecord:
    """Make the :class:`ResultRecord` of a whole ``register()`` run (CLI, benchmark).

    Parameters
    ----------
    result : RegistrationResult
    T_truth : (4, 4) float64 or None
        Known ``T_target_source`` (world frame); adds the truth errors.
    **context
        More ResultRecord fields: ``target_file``, ``source_file``, ``timings_s``
        (merged over the run's own), ``amrst_version``.

    Returns
    -------
    ResultRecord
    """
    truth: dict[str, TruthErrors] = {}
    if T_truth is not None:
        src = result.source.cloud.world_xyz
        T_truth = np.asarray(T_truth, float)
        truth = {
            "coarse": truth_errors(result.T_coarse, T_truth, src),
            "fine": truth_errors(result.T_target_source, T_truth, src),
        }
    timings = {**result.timings, **context.pop("timings_s", {})}
    counts = {
        "key_points": {
            # A finished registration has both scans' key points.
            "target": len(cast("KeypointResult", result.target.keypoints).xyz),
            "source": len(cast("KeypointResult", result.source.keypoints).xyz),
        },
        "tetrahedron_matches": result.matches.n_matches,
        "candidates": len(result.matches.candidates),
        "wood_fraction": {
            "target": result.target.separation.wood_fraction,
            "source": result.source.separation.wood_fraction,
        },
    }
    return ResultRecord(
        T_target_source=result.T_target_source,
        T_coarse=result.T_coarse,
        target_name=result.target.cloud.name,
        source_name=result.source.cloud.name,
        coarse=result.coarse,
        fine=result.fine,
        metrics_coarse=result.metrics_coarse.as_dict(),
        metrics_fine=result.metrics_fine.as_dict(),
        truth=truth,
        tree=result.tree,
        timings_s=timings,
        confidence=result.confidence,
        message=result.message,
        counts=counts,
        quality=quality_section(result),
        strength=None if result.strength is None else dict(result.strength.values),
        **context,
    )


# Keys of the files written before schema_version 2, and where they went.
_OLD_TRANSFORM_KEYS = {
    "coarse_match_rank": ("coarse_candidate", "rank"),  # the app
    "coarse_origin": ("coarse_candidate", "origin"),  # the app
    "fine_method": ("fine", "method"),  # the app
    "fine_converged": ("fine", "converged"),  # the app
}


def upgrade_result(doc: Mapping[str, Any], kind: str) -> dict[str, Any]:
    """Read a transform.json or metrics.json of any version into the current layout.

    Parameters
    ----------
    doc : mapping
        The file's JSON object.
    kind : {"transform", "metrics"}

    Returns
    -------
    dict
        With ``schema_version`` 2; files already current are returned as a copy.
    """
    out = dict(doc)
    if int(out.get("schema_version", 1)) >= RESULT_SCHEMA_VERSION:
        return out
    out["schema_version"] = RESULT_SCHEMA_VERSION
    if kind == "transform":
        if out.get("confidence") is None and "coarse_confidence" in out:
            out["confidence"] = out.pop("coarse_confidence")
        for old, (section, key) in _OLD_TRANSFORM_KEYS.items():
            if old in out:
                value = out.pop(old)
                out[section] = {**(out.get(section) or {}), key: value}
        out.setdefault("stage", "fine" if out.get("fine") else "coarse")
        return out
    truth: dict[str, Any] = dict(out.get("truth") or {})
    for stage in ("coarse", "fine"):  # the app wrote truth_* inside each stage
        part = out.get(stage)
        if isinstance(part, dict):
            inline = {k[6:]: v for k, v in part.items() if k.startswith("truth_")}
            if inline:
                out[stage] = {
                    k: v for k, v in part.items() if not k.startswith("truth_")
                }
                truth[stage] = inline
    if truth:
        out["truth"] = truth
    return out
