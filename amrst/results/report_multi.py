"""The report of a multi-scan registration: one HTML file, as for a pair.

``amrst register REF S2 S3 ... --report`` writes it. It lists every scan with the path
it took to the reference (or "not reached"), every link with its state, score,
confidence and NN-RMSE, the joint refinement, the loop closures, the pictures of the
reference against all other scans moved onto it (the pair report's pictures, drawn
by :mod:`amrst.results.report_images`), the tree measurements and the parameters.
Sections and style are those of :mod:`amrst.results.report_html`. No Qt, no pyvista.
"""

from __future__ import annotations

import html
import math
from typing import TYPE_CHECKING, Any

import numpy as np

from amrst.results.report_html import (
    STYLE,
    html_table,
    images_section,
    params_section,
    tree_section,
)
from amrst.review.verdict import TEXT_RGB

if TYPE_CHECKING:
    from collections.abc import Mapping, Sequence

    from amrst.multiscan.register import MultiScanResult


def _e(value: object) -> str:
    return html.escape(str(value))


def _cm(value: Any) -> str:
    if value is None or (isinstance(value, float) and math.isnan(value)):
        return "–"
    return f"{float(value) * 100:.2f} cm"


def how_reached(result: MultiScanResult, k: int) -> str:
    """How scan ``k`` reaches the reference, in words (as ``amrst register`` prints)."""
    if k == result.reference:
        return "reference"
    path = result.paths[k]
    if path is None:
        return "NOT reached (no verified link)"
    return "via " + " → ".join(map(str, path))


def _verdict(result: MultiScanResult) -> str:
    status = result.status
    colour = TEXT_RGB[status]
    n, reached = len(result.scans), sum(result.reached)
    why = (
        f"{reached} of {n} scans reach the reference through verified links; the "
        f"weakest link of the spanning tree has confidence {result.confidence:.0%}."
    )
    nxt = (
        "Nothing more is needed; check the links below at a glance."
        if status == "registered"
        else "Open the scans in amrst-gui, review the links that are not registered "
        "and recover the scans not reached by hand (point pairs, nudge or a typed "
        "transform)."
    )
    return (
        f'<div class="verdict" style="border-color:{colour}">'
        f'<p class="headline" style="color:{colour}">{_e(status.capitalize())}</p>'
        f"<p><b>Why:</b> {_e(why)}</p><p><b>Next:</b> {_e(nxt)}</p></div>"
    )


def _scans(
    result: MultiScanResult,
    labels: Sequence[str],
    truth: Sequence[Mapping[str, Any] | None],
) -> str:
    rows, mats = [], []
    for k, cloud in enumerate(result.scans):
        err = truth[k] if k < len(truth) else None
        rows.append(
            [
                str(k),
                _e(labels[k] if k < len(labels) else cloud.name),
                f"{len(cloud):,}",
                _e(how_reached(result, k)),
                "–"
                if err is None
                else f"{err['rotation_error_deg']:.3f}°, {_cm(err['gt_rmse_m'])}",
            ]
        )
        T = result.T_reference_scan[k]
        if T is not None and k != result.reference:
            text = "\n".join(" ".join(f"{v:12.6f}" for v in row) for row in T)
            mats.append(f"<h3>T_reference_scan, scan {k}</h3><pre>{text}</pre>")
    head = ["Scan", "File", "Points", "Reaches the reference", "Truth error"]
    return "<h2>Scans</h2>" + html_table(head, rows) + "".join(mats)


def _links(result: MultiScanResult) -> str:
    rows = []
    for link in result.links:
        m = link.metrics
        rows.append(
            [
                f"{link.target} ← {link.source}",
                _e(link.status),
                f"{link.score:.0%}",
                f"{link.confidence:.0%}",
                "–" if m is None else _cm(m.rmse_overlap_m),
                "–" if m is None else f"{m.overlap_fraction:.0%}",
                "yes" if link.in_tree else "",
                _e(link.message),
            ]
        )
    head = [
        "Link",
        "State",
        "Score",
        "Confidence",
        "NN-RMSE (overlap)",
        "Overlap",
        "In the tree",
        "Message",
    ]
    out = (
        f"<h2>Links</h2><p>{len(result.links)} pairs registered and verified; the "
        "spanning tree uses the best verified ones. Score: share of the sampled source "
        "points within the verification distance of the target.</p>"
        + html_table(head, rows)
    )
    if result.joint is not None:
        j = result.joint
        out += (
            f"<p>Joint refinement: mean NN-RMSE {_cm(j.rmse_before_m)} → "
            f"{_cm(j.rmse_after_m)} ({'kept' if j.kept else 'not kept: worse'}).</p>"
        )
    if result.loops:
        loops = ", ".join(f"{k}: {_cm(v)}" for k, v in result.loops.items())
        out += f"<p>Verified links left out of the tree disagree by {_e(loops)}.</p>"
    return out


def render_multi_images(result: MultiScanResult) -> dict[str, bytes]:
    """Draw the pair report's pictures: the reference against every other scan moved."""
    from amrst.results.report_images import render_all
    from amrst.review.quality import stem_slices
    from amrst.types import local_transform

    ref = result.scans[result.reference]
    moved = [
        result.scans[k].xyz @ L[:3, :3].T + L[:3, 3]
        for k, T in enumerate(result.T_reference_scan)
        if T is not None and k != result.reference
        for L in (local_transform(T, ref, result.scans[k]),)
    ]
    if not moved:
        return {}
    others = np.vstack(moved)
    slices = stem_slices(ref.xyz, others, params=result.params.measure)
    return render_all(ref.xyz, others, slices)


def build_multi_html(
    result: MultiScanResult,
    labels: Sequence[str],
    images: Mapping[str, bytes],
    truth: Sequence[Mapping[str, Any] | None] = (),
) -> str:
    """Build the whole multi-scan report page as one string."""
    from amrst import __version__

    ref = labels[result.reference] if result.reference < len(labels) else "scan 0"
    title = f"Registration of {len(result.scans)} scans onto {ref}"
    timings = ", ".join(f"{k} {v:.2f} s" for k, v in result.timings.items())
    return (
        f"<!DOCTYPE html><html lang='en'><head><meta charset='utf-8'>"
        f"<title>{_e(title)}</title><style>{STYLE}</style></head><body>"
        f"<h1>{_e(title)}</h1>"
        + _verdict(result)
        + _scans(result, labels, truth)
        + _links(result)
        + images_section(images)
        + tree_section(result.tree)
        + (f"<p>Time per step: {_e(timings)}</p>" if timings else "")
        + params_section(result.params)
        + f"<p><small>Written by AMRST {__version__}.</small></p></body></html>"
    )


def multi_report_page(
    result: MultiScanResult,
    labels: Sequence[str],
    truth: Sequence[Mapping[str, Any] | None] = (),
    images: Mapping[str, bytes] | None = None,
) -> str:
    """Return the multi-scan report's HTML.

    ``truth``: per scan, the truth errors of ``scans.json`` (or None).
    """
    pictures = dict(images) if images is not None else render_multi_images(result)
    return build_multi_html(result, labels, pictures, truth)
