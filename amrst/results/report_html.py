"""The registration report: one self-contained HTML file a browser opens alone.

Everything a technician signs off by, in one page: the inputs, the verdict and why,
the chosen candidate and its alternatives, the metrics with their meaning, the
pictures (overlay, distance colouring, distance histogram, stem slices; PNGs embedded
as base64), the tree measurements and the parameters. ``amrst register --report``
and the app's Export both write it with the result's files (:func:`report_page`). No
Qt, no pyvista.
"""

from __future__ import annotations

import base64
import dataclasses
import html
import math
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import numpy as np

from amrst.results.metric_doc import METRIC_ROWS
from amrst.review.verdict import TEXT_RGB
from amrst.stages.metrics import REGISTERED_DEG, REGISTERED_RMSE_M

if TYPE_CHECKING:
    from collections.abc import Mapping

    from amrst.measure import TreeMeasures
    from amrst.params import RegistrationParams
    from amrst.review.verdict import Verdict
    from amrst.stages.candidates import Candidate
    from amrst.types import Cloud

REPORT_NAME = "report.html"
_ALTERNATIVES = 10  # candidates listed besides the chosen one
_IMAGES = (
    ("overlay", "Overlay: target amber, moved source blue"),
    ("distance", "Distance colouring"),
    ("histogram", "Distance histogram"),
    ("slices", "Stem slices (good: circles coincide, centres under 15 mm apart)"),
)


@dataclass(frozen=True, kw_only=True)
class ReportInputs:
    """What the report shows; built by the CLI (:func:`inputs_from_result`) or the app.

    ``T_local`` maps the source's local frame into the target's (as the engine
    works); ``metrics`` and ``truth`` are keyed by stage ("coarse", "fine"), each a
    mapping of the keys of ``amrst.results.metric_doc.METRIC_ROWS`` to values.
    """

    target: Cloud
    source: Cloud
    target_file: str
    source_file: str
    T_local: np.ndarray
    stage: str  # "fine" or "coarse": the stage T_local comes from
    verdict: Verdict
    candidates: tuple[Candidate, ...]
    chosen_id: int | None
    params: RegistrationParams
    rejected_ids: frozenset[int] = frozenset()
    metrics: Mapping[str, Mapping[str, Any]] = field(default_factory=dict)
    truth: Mapping[str, Mapping[str, Any]] = field(default_factory=dict)
    tree: Mapping[str, TreeMeasures] = field(default_factory=dict)
    timings: Mapping[str, float] = field(default_factory=dict)
    override: Mapping[str, str] | None = None
    manual_labels: Mapping[int, str] = field(default_factory=dict)
    notes: tuple[str, ...] = ()  # e.g. why Fine's result was dropped for a manual pose
    # metrics.json's ``quality`` (overlap distances, stem slices) and ``strength``.
    quality: Mapping[str, Any] | None = None
    strength: Mapping[str, float] | None = None

    @property
    def moved_source_xyz(self) -> np.ndarray:
        """Source points under ``T_local``, in the target's local frame."""
        T = self.T_local
        return np.asarray(self.source.xyz @ T[:3, :3].T + T[:3, 3])


def inputs_from_result(
    result: Any,
    target: Cloud,
    source: Cloud,
    *,
    target_file: str,
    source_file: str,
    T_truth: np.ndarray | None = None,
) -> ReportInputs:
    """Report inputs of a finished ``amrst.pipeline.RegistrationResult`` (the CLI)."""
    from amrst.results.documents import quality_section
    from amrst.review.verdict import judge_result
    from amrst.types import local_transform

    params = result.params
    T_local = local_transform(result.T_target_source, target, source)
    coarse, fine = result.coarse, result.fine
    metrics = {
        "coarse": {**result.metrics_coarse.as_dict(), "confidence": coarse.confidence},
        "fine": {
            **result.metrics_fine.as_dict(),
            "iterations": fine.iterations,
            "fitness": fine.fitness,
            "inlier_rmse_m": fine.inlier_rmse_m,
            "converged": fine.converged,
        },
    }
    truth: dict[str, dict[str, Any]] = {}
    if T_truth is not None:
        from amrst.stages.metrics import truth_errors

        xyz = source.world_xyz[:: max(1, len(source) // 20_000)]
        for stage, T in (
            ("coarse", result.T_coarse),
            ("fine", result.T_target_source),
        ):
            truth[stage] = truth_errors(T, T_truth, xyz).as_dict()
    return ReportInputs(
        target=target,
        source=source,
        target_file=target_file,
        source_file=source_file,
        T_local=T_local,
        stage="fine",
        verdict=judge_result(result, params),
        candidates=tuple(result.matches.candidates),
        chosen_id=int(coarse.candidate.id),
        params=params,
        metrics=metrics,
        truth=truth,
        tree=dict(result.tree),
        timings=dict(result.timings),
        quality=quality_section(result),
        strength=None if result.strength is None else dict(result.strength.values),
    )


def render_images(inputs: ReportInputs) -> dict[str, bytes]:
    """Draw the report's pictures with matplotlib (Agg); PNG bytes by name."""
    from amrst.results.report_images import render_all
    from amrst.review.quality import stem_slices

    moved = inputs.moved_source_xyz
    slices = stem_slices(inputs.target.xyz, moved, params=inputs.params.measure)
    return render_all(inputs.target.xyz, moved, slices)


def report_page(inputs: ReportInputs, images: Mapping[str, bytes] | None = None) -> str:
    """Return the report's HTML page.

    ``images`` (PNG bytes by name) default to :func:`render_images`. The page is
    written with the result's other files, in one atomic step
    (``export_registration(extra_files=...)``).
    """
    pictures = dict(images) if images is not None else render_images(inputs)
    return build_html(inputs, pictures)


# ------------------------------------------------------------------ the page
def _e(value: object) -> str:
    return html.escape(str(value))


def _fmt(kind: str, value: Any) -> str:
    if value is None or (isinstance(value, float) and math.isnan(value)):
        return "–"
    if kind == "cm":
        return f"{float(value) * 100:.2f} cm"
    if kind == "%":
        return f"{float(value):.0%}"
    if kind == "bool":
        return "yes" if value else "no"
    if kind == "deg":
        return f"{float(value):.3f}°"
    if kind == "count":
        return f"{int(value):,}"
    return _e(value)


def html_table(head: list[str], rows: list[list[str]]) -> str:
    """Return an HTML table of already escaped cells."""
    top = "".join(f"<th>{h}</th>" for h in head)
    body = "".join("<tr>" + "".join(f"<td>{c}</td>" for c in r) + "</tr>" for r in rows)
    return f"<table><tr>{top}</tr>{body}</table>"


def _inputs(r: ReportInputs) -> str:
    from amrst.types import world_transform

    rows = []
    for role, cloud, name in (
        ("Target (fixed)", r.target, r.target_file),
        ("Source (moved)", r.source, r.source_file),
    ):
        offset = "none" if not np.any(cloud.offset) else _e(np.round(cloud.offset, 3))
        rows.append([role, _e(name), f"{len(cloud):,}", offset])
    T = world_transform(r.T_local, r.target, r.source)
    matrix = "\n".join(" ".join(f"{v:12.6f}" for v in row) for row in T)
    return (
        "<h2>Inputs</h2>"
        + html_table(["Scan", "File", "Points", "Offset"], rows)
        + f"<h3>T_target_source (world, after {_e(r.stage)})</h3><pre>{matrix}</pre>"
    )


def _verdict(r: ReportInputs) -> str:
    v = r.verdict
    colour = TEXT_RGB.get(v.status, "#333")
    out = (
        f'<div class="verdict" style="border-color:{colour}">'
        f'<p class="headline" style="color:{colour}">{_e(v.headline)}</p>'
        f"<p><b>Why:</b> {_e(v.reason)}</p><p><b>Next:</b> {_e(v.next_step)}</p>"
    )
    for note in r.notes:
        out += f"<p><b>Note:</b> {_e(note)}</p>"
    if r.override:
        out += (
            "<p><b>Exported on purpose although the verdict is "
            f"'{_e(r.override.get('verdict_status', ''))}'</b> "
            f"({_e(r.override.get('by', ''))}).</p>"
        )
    return out + "</div>"


def _candidates(r: ReportInputs) -> str:
    rows = []
    chosen = [c for c in r.candidates if c.id == r.chosen_id]
    others = [c for c in r.candidates if c.id != r.chosen_id][:_ALTERNATIVES]
    for c in chosen + others:
        status = (
            "<b>chosen</b>"
            if c.id == r.chosen_id
            else ("rejected by the user" if c.id in r.rejected_ids else "")
        )
        how = r.manual_labels.get(int(c.id), "")
        rows.append(
            [
                str(c.rank),
                str(c.id),
                _e(c.origin) + (f" ({_e(how)})" if how else ""),
                f"{c.score:.0%}",
                str(c.support),
                status,
                _e(c.explanation),
            ]
        )
    n = len(r.candidates)
    return (
        f"<h2>Chosen candidate and alternatives</h2><p>{n} candidates; "
        f"{len(r.rejected_ids)} rejected by the user. Score: share of the sampled "
        "source points within the verification distance of the target.</p>"
        + html_table(
            ["Rank", "Id", "From", "Score", "Support", "Status", "Explanation"], rows
        )
    )


def _metrics(r: ReportInputs) -> str:
    stages = [s for s in ("coarse", "fine") if s in r.metrics or s in r.truth]
    rows = []
    for key, name, kind, meaning in METRIC_ROWS:
        values = []
        for s in stages:
            merged = {**r.metrics.get(s, {}), **_with_registered(r.truth.get(s, {}))}
            values.append(_fmt(kind, merged.get(key)))
        if any(v != "–" for v in values):
            rows.append([_e(name), *values, _e(meaning)])
    head = ["Metric", *(s.capitalize() for s in stages), "What it means"]
    timings = ", ".join(f"{k} {v:.2f} s" for k, v in r.timings.items())
    return (
        "<h2>Metrics</h2>"
        + html_table(head, rows)
        + (f"<p>Time per step: {_e(timings)}</p>" if timings else "")
    )


_AXIS_WORDS = {
    "tx": "shift along x",
    "ty": "shift along y",
    "tz": "height (z)",
    "rx": "tilt about x",
    "ry": "tilt about y",
    "rz": "turn about the stem (z)",
}


def quality_html(r: ReportInputs) -> str:
    """Return the section of what both scans saw: distances, slices, strength."""
    from amrst.review.strength import WEAK_STRENGTH

    parts = []
    d = (r.quality or {}).get("distance")
    if d:
        parts.append(
            f"<p>Where both scans saw the scene ({int(d['n_points_measured'])} source "
            f"points, {d['overlap_fraction']:.0%} of them): median distance "
            f"{_fmt('cm', d['median_m'])}, {_fmt('%', d['within_2cm_fraction'])} "
            f"within 2 cm, 95th percentile {_fmt('cm', d['p95_m'])}. Good: a median "
            "under 1.5 cm and 60 % or more within 2 cm. These are the figures to "
            "judge the pose by; the metrics over every point above include parts "
            "one scan alone saw.</p>"
        )
    slices = (r.quality or {}).get("stem_slices") or []
    if slices:
        rows = [
            [
                _e(f"{sl['height_m']:g} m"),
                _fmt("cm", sl.get("diameter_m")),
                _fmt("cm", sl["offset_m"]),
                _e(sl["status"]),
            ]
            for sl in slices
        ]
        head = ["Slice", "⌀ (both scans)", "Centres apart", "Status"]
        parts.append(
            "<p>Stem slices of the tree of interest alone:</p>" + html_table(head, rows)
        )
    if r.strength:
        rows = [
            [
                _e(_AXIS_WORDS.get(k, k)),
                _e(f"{v:.2f}" if v == v else "n/a"),
                _e("weak: check the slices" if v == v and v < WEAK_STRENGTH else ""),
            ]
            for k, v in r.strength.items()
        ]
        parts.append(
            "<p>Strength per axis (0-1): how firmly the final alignment holds each "
            f"axis; under {WEAK_STRENGTH:g} the surfaces slide along it.</p>"
            + html_table(["Axis", "Strength", ""], rows)
        )
    if not parts:
        return ""
    return "<h2>Where both scans saw the scene</h2>" + "".join(parts)


def _with_registered(truth: Mapping[str, Any]) -> dict[str, Any]:
    out = dict(truth)
    if "registered" not in out and "rotation_error_deg" in out:
        out["registered"] = (
            out["rotation_error_deg"] < REGISTERED_DEG
            and out["gt_rmse_m"] < REGISTERED_RMSE_M
        )
    return out


def tree_section(tree: Mapping[str, TreeMeasures]) -> str:
    """Return the tree measurements section: one row per measured cloud."""
    if not tree:
        return "<h2>Tree measurements</h2><p>None (no registration measured).</p>"
    rows = []
    for name, m in tree.items():
        rows.append(
            [
                _e(name),
                f"{m.height_m:.2f} m",
                "–" if math.isnan(m.dbh_m) else f"{m.dbh_m * 100:.1f} cm",
                "–" if m.stem is None else f"{m.stem.arc_deg:.0f}°",
                f"{m.crown_width_m:.1f} m",
                f"{m.crown_area_m2:.1f} m²",
                _e(m.note),
            ]
        )
    return "<h2>Tree measurements</h2>" + html_table(
        [
            "Cloud",
            "Height",
            "DBH",
            "Stem seen over",
            "Crown width",
            "Crown area",
            "Note",
        ],
        rows,
    )


def params_section(params: RegistrationParams) -> str:
    """Return the parameters section: every group's values with their units."""
    rows = []
    for group in dataclasses.fields(params):
        values = getattr(params, group.name)
        if not dataclasses.is_dataclass(values):
            rows.append([_e(group.name), "", _e(values), ""])
            continue
        for f in dataclasses.fields(values):
            unit = f.metadata.get("unit", "")
            rows.append(
                [_e(group.name), _e(f.name), _e(getattr(values, f.name)), _e(unit)]
            )
    return "<h2>Parameters</h2>" + html_table(["Group", "Name", "Value", "Unit"], rows)


def images_section(images: Mapping[str, bytes]) -> str:
    """Return the pictures section: the PNGs embedded, with their captions."""
    out = ["<h2>Pictures</h2>"]
    for name, caption in _IMAGES:
        png = images.get(name)
        if png is None:
            continue
        data = base64.b64encode(png).decode("ascii")
        out.append(
            f'<figure><img alt="{_e(caption)}" src="data:image/png;base64,{data}">'
            f"<figcaption>{_e(caption)}</figcaption></figure>"
        )
    return "".join(out)


STYLE = """
body{font-family:sans-serif;max-width:1150px;margin:1em auto;color:#222}
table{border-collapse:collapse;margin:.5em 0}td,th{border:1px solid #ccc;
padding:3px 6px;text-align:left;vertical-align:top;font-size:90%}
th{background:#eee}.verdict{border:3px solid;padding:.5em 1em;border-radius:6px}
.headline{font-size:150%;font-weight:bold;margin:.2em 0}img{max-width:100%}
figure{margin:1em 0}figcaption{font-style:italic}pre{background:#f6f6f6;padding:6px}
"""


def build_html(inputs: ReportInputs, images: Mapping[str, bytes]) -> str:
    """Build the whole report page as one string."""
    from amrst import __version__

    title = f"Registration of {inputs.source_file} onto {inputs.target_file}"
    return (
        f"<!DOCTYPE html><html lang='en'><head><meta charset='utf-8'>"
        f"<title>{_e(title)}</title><style>{STYLE}</style></head><body>"
        f"<h1>{_e(title)}</h1>"
        + _verdict(inputs)
        + _inputs(inputs)
        + _candidates(inputs)
        + quality_html(inputs)
        + _metrics(inputs)
        + images_section(images)
        + tree_section(inputs.tree)
        + params_section(inputs.params)
        + f"<p><small>Written by AMRST {__version__}.</small></p></body></html>"
    )
