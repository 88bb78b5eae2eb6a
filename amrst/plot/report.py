"""The plot's report: one self-contained HTML page of what the run handed over.

It is built from ``plot.json`` and the inventory's rows (with the technician's
marks): the scans and their states, the links, the stem map (matplotlib's Agg, a PNG
embedded as base64) and the tree list. ``amrst plot --report`` writes it with the run;
the app writes it again from the folder's files after a review
(``amrst.plot.export.write_report``), so it says what those files say. No Qt.
"""

from __future__ import annotations

import base64
from typing import TYPE_CHECKING, Any

import numpy as np

from amrst.plot.flags import height_words
from amrst.plot.review import NOT_A_TREE, unsure_scans
from amrst.plot.stand import PlotArea, counted, stand
from amrst.results.report_html import STYLE, html_table

if TYPE_CHECKING:
    from collections.abc import Mapping, Sequence

REPORT = "report.html"
#: Tree fills by DBH quality, the ring of the technician's mark and link colours by
#: state: the report's and the app's stem map.
QUALITY_RGB = {"ok": "#4caf50", "check": "#ffb300", "none": "#9e9e9e"}
# Light blue, not white, for ok: the report's map is drawn on white.
MARK_RGB = {"ok": "#29b6f6", "check": "#f44336", "not a tree": "#e040fb"}
STATE_RGB = {
    "registered": "#4caf50",
    "accepted": "#26a69a",
    "needs review": "#ffb300",
    "failed": "#f44336",
}
#: A scanner this far from every tree is not drawn (an older plot.json gives the
#: file origin, which a georeferenced file holds far away).
SCAN_REACH_M = 60.0
#: Large (georeferenced) coordinates are drawn from a round origin, in these steps.
ORIGIN_STEP_M = 100.0


def build_report(doc: Mapping[str, Any], rows: Sequence[Mapping[str, Any]]) -> str:
    """Return the report page for plot.json's ``doc`` and the inventory's ``rows``."""
    from amrst import __version__

    scans = doc["scans"]
    title = f"Forest plot of {len(scans)} scans"
    png = base64.b64encode(stem_map_png(doc, rows)).decode("ascii")
    return (
        f"<!DOCTYPE html><html lang='en'><head><meta charset='utf-8'>"
        f"<title>{_e(title)}</title><style>{STYLE}</style></head><body>"
        f"<h1>{_e(title)}</h1>"
        + _summary(doc, rows)
        + '<h2>Stem map</h2><figure><img alt="stem map" '
        + f'src="data:image/png;base64,{png}"><figcaption>Every tree at its stem '
        "base, its dot sized by its DBH (yours where you measured it) and filled by "
        "the DBH's quality (green ok, amber check, grey none), ringed blue where you "
        "marked it ok, red where check, crossed where not a tree; the scans "
        "(triangles) and their links by state; the plot's edge dotted when it has "
        "a radius.</figcaption></figure>"
        + _scans(doc)
        + _links(doc)
        + _trees(rows, _unsure(doc))
        + f"<p><small>Written by AMRST {__version__}"
        + (f" on {_e(doc['written_utc'][:10])}" if doc.get("written_utc") else "")
        + "; coordinates in metres, the first scan's file coordinates (world "
        "coordinates when it is georeferenced), as in trees.csv.</small></p>"
        "</body></html>"
    )


def stem_map_png(doc: Mapping[str, Any], rows: Sequence[Mapping[str, Any]]) -> bytes:
    """Draw the plot from above: trees, scans and links; return the PNG."""
    from matplotlib.patches import Circle

    from amrst.results.report_images import new_figure, png_bytes

    xy = np.array([[_num(r["x_m"]), _num(r["y_m"])] for r in rows], float)
    xy = xy.reshape(-1, 2)
    scans = _scan_xy(doc, xy)
    every = np.vstack([xy, *(p[None] for p in scans.values())]) if scans else xy
    origin = _origin(every)
    fig = new_figure(8, 8)
    ax = fig.subplots()
    ax.set_aspect("equal")
    for link in doc.get("links", []):
        a, b = scans.get(link["target"]), scans.get(link["source"])
        if a is None or b is None:
            continue
        state = "accepted" if link.get("accepted") else link.get("status", "")
        (x0, y0), (x1, y1) = a - origin, b - origin
        ax.plot(
            [x0, x1],
            [y0, y1],
            color=STATE_RGB.get(state, "#bdbdbd"),
            lw=2.5 if link.get("in_tree") else 1.2,
            ls="-" if link.get("in_tree") else "--",
            zorder=1,
        )
    for k, p in scans.items():
        x, y = p - origin
        ax.plot(x, y, marker="^", ms=11, color="#455a64", zorder=3)
        ax.annotate(f"S{k + 1}", (x, y), xytext=(6, -12), textcoords="offset points")
    for r, (x, y) in zip(rows, xy - origin, strict=True):
        hand = _num(r.get("dbh_hand_m"))
        dbh = hand if np.isfinite(hand) else _num(r.get("dbh_m"))  # yours first
        size = 30 + 900 * (dbh if np.isfinite(dbh) else 0.05)
        mark = str(r.get("mark", ""))
        ax.scatter(
            x,
            y,
            s=size,
            c=QUALITY_RGB.get(str(r.get("dbh_quality")), "#9e9e9e"),
            edgecolors=MARK_RGB.get(mark, "#212121"),
            linewidths=2.0 if mark in ("ok", "check") else 0.6,
            zorder=2,
        )
        if mark == NOT_A_TREE:
            ax.scatter(x, y, s=size, marker="x", c="#212121", zorder=3)
        ax.annotate(
            str(r["tree_id"]), (x, y), xytext=(5, 5), textcoords="offset points"
        )
    area = PlotArea.from_dict(doc.get("plot_area"))
    if area is not None:
        ax.add_patch(
            Circle(
                np.asarray(area.centre_xy) - origin,
                area.radius_m,
                fill=False,
                ls=":",
                color="#455a64",
                zorder=0,
            )
        )
    unit = "m" if not origin.any() else f"m (from {origin[0]:.0f}, {origin[1]:.0f})"
    ax.set_xlabel(f"x, {unit}")
    ax.set_ylabel("y, m")
    ax.grid(alpha=0.3)
    return png_bytes(fig)


def _scan_xy(doc: Mapping[str, Any], trees: np.ndarray) -> dict[int, np.ndarray]:
    """Where each placed scan's scanner stood, when known and among the trees."""
    from amrst.plot.view import scanner_position

    out = {}
    for k, scan in enumerate(doc["scans"]):
        at = scanner_position(scan)
        if at is None:
            continue
        p = at[:2]
        near = not len(trees) or np.hypot(*(trees - p).T).min() <= SCAN_REACH_M
        if near:
            out[k] = p
    return out


def _origin(xy: np.ndarray) -> np.ndarray:
    if not len(xy) or np.abs(xy).max() < 1e4:
        return np.zeros(2)
    return np.asarray(np.floor(xy.min(axis=0) / ORIGIN_STEP_M) * ORIGIN_STEP_M)


def _summary(doc: Mapping[str, Any], rows: Sequence[Mapping[str, Any]]) -> str:
    states = [s.get("state", s.get("status", "")) for s in doc["scans"]]
    counts = ", ".join(
        f"{states.count(s)} {s}"
        for s in ("registered", "accepted", "needs review", "failed")
        if states.count(s)
    )
    sure = all(s in ("registered", "accepted") for s in states)
    colour = STATE_RGB["registered" if sure else "needs review"]
    bundle = _num(doc.get("bundle_rmse_m"))
    good = sum(1 for r in rows if r.get("mark") == "ok")
    checked = sum(1 for r in rows if r.get("mark") == "check")
    dropped = sum(1 for r in rows if r.get("mark") == NOT_A_TREE)
    by_hand = sum(1 for r in rows if r.get("dbh_hand_m") not in (None, ""))
    waiting = _unsure(doc)
    unsure = sum(1 for r in rows if _to_check(r, waiting))
    return (
        f'<div class="verdict" style="border-color:{colour}">'
        f'<p class="headline">{counted(len(rows), "tree")}; scans: {_e(counts)}</p>'
        + (
            f"<p>No tree listed: {_e(doc['no_tree_why'])}.</p>"
            if doc.get("no_tree_why")
            else ""
        )
        + (
            f"<p>{counted(unsure, 'tree')} seen from a scan that needs review: "
            "their figures rest on its pose (Seen from says which; check the "
            "link, then accept it or place the scan by hand).</p>"
            if unsure
            else ""
        )
        + f"<p>Bundle error {_cm(bundle)} (the RMS of the scans' residuals: each "
        "scan's distance to the surfaces of the others where they overlap, at the "
        f"final poses); {counted(good, 'tree')} marked ok, {checked} marked check, "
        f"{dropped} "
        f"marked not a tree and {counted(by_hand, 'DBH')} measured by you.</p>"
        + _stand(rows, PlotArea.from_dict(doc.get("plot_area")))
        + "</div>"
    )


def _stand(rows: Sequence[Mapping[str, Any]], area: PlotArea | None) -> str:
    st = stand(rows, area)
    height = (
        f"Lorey's mean height {st.lorey_height_m:.1f} m over {st.with_height} of "
        f"the {counted(st.trees, 'tree')} (those with a DBH and a height flagged ok)"
        if st.with_height
        else "no mean height: no tree with a DBH has a height flagged ok"
    )
    if area is None:
        where, per_ha = "", ""
        edge = "; not per hectare: give the plot's radius, amrst plot --plot-radius"
    else:
        cx, cy = area.centre_xy
        where = (
            f" within {area.radius_m:g} m of ({cx:.2f}, {cy:.2f}), "
            f"{area.hectares:.4f} ha ({counted(st.outside, 'listed tree')} "
            "outside it left out)"
        )
        per_ha = (
            f" ({st.trees_per_ha:.0f} stems/ha, {st.basal_area_m2_per_ha:.1f} m²/ha)"
        )
        edge = ""
    return (
        f"<p>Stand{_e(where)}: {counted(st.trees, 'tree')}, {st.with_dbh} with a "
        "DBH; basal "
        f"area {st.basal_area_m2:.3f} m²{per_ha}, quadratic mean DBH "
        f"{_cm(st.qmd_m)}; {height} (trees marked not a tree left out, your DBHs "
        f"used{edge}).</p>"
    )


def _scans(doc: Mapping[str, Any]) -> str:
    rows = []
    for k, s in enumerate(doc["scans"]):
        path = s.get("path")
        rows.append(
            [
                f"S{k + 1}",
                _e(s.get("label", "")),
                _e(s.get("name", "")),  # dropped below when no scan has a name
                _e(s.get("state", s.get("status", ""))),
                _e(
                    "reference"
                    if k == 0
                    else "–"
                    if path is None
                    else "–".join(f"S{p}" for p in path)
                ),
                _e(s.get("stems", "")),
                _cm(_num(s.get("residual_m"))),
            ]
        )
    head = ["Scan", "File", "Name", "State", "Placed through", "Stems", "Residual"]
    if not any(row[2] for row in rows):
        head, rows = head[:2] + head[3:], [r[:2] + r[3:] for r in rows]
    return "<h2>Scans</h2>" + html_table(head, rows)


def _links(doc: Mapping[str, Any]) -> str:
    rows = []
    for ln in doc.get("links", []):
        m = ln.get("metrics") or {}
        state = "accepted" if ln.get("accepted") else ln.get("status", "")
        if ln.get("loop_confirmed") and state != "registered":
            state = "registered (loop)"
        rows.append(
            [
                f"S{ln['target'] + 1}–S{ln['source'] + 1}"
                + (" ★" if ln.get("in_tree") else ""),
                _e(state),
                _e(ln.get("origin", "")),
                _e(ln.get("stems_shared", "")),
                _pct(m.get("overlap_fraction")),
                _cm(_num(ln.get("residual_m"))),
                _e(ln.get("message", "")),
            ]
        )
    head = ["Link", "State", "By", "Stems", "Overlap", "Residual", "Why"]
    return (
        "<h2>Links</h2><p>★: in the spanning tree that places the scans. Residual: "
        "the second scan's distance to the first one's surfaces at the link's "
        "pose.</p>"
    ) + (html_table(head, rows))


def _unsure(doc: Mapping[str, Any]) -> frozenset[int]:
    """Return the scans, from 1, that need review as plot.json's states say."""
    return unsure_scans([s.get("state", s.get("status", "")) for s in doc["scans"]])


def _to_check(row: Mapping[str, Any], unsure: frozenset[int]) -> str:
    """Return the scans a tree is seen from that need review, as trees.csv does."""
    seen = str(row.get("seen_from", "")).split(";")
    return ";".join(k for k in seen if k.strip().isdecimal() and int(k) in unsure)


def _trees(rows: Sequence[Mapping[str, Any]], unsure: frozenset[int]) -> str:
    in_plot = any(r.get("in_plot") for r in rows)  # a plot radius was given
    body = []
    for r in rows:
        check = _to_check(r, unsure)
        body.append(
            [
                _e(r["tree_id"]),
                f"{_num(r['x_m']):.2f}, {_num(r['y_m']):.2f}, {_num(r['z_m']):.2f}",
                _e(height_words(_num(r.get("height_m")), _num(r.get("height_seen_m"))))
                + f" ({_e(r.get('height_flag', ''))})",
                _fixed(_num(r.get("dbh_m")) * 100, 1)
                + f" ({_e(r.get('dbh_quality', ''))})"
                + (
                    f"<br><small>{_e(r['dbh_why'])}</small>" if r.get("dbh_why") else ""
                ),
                _fixed(r.get("crown_width_m"), 1),
                _e(r.get("seen_from", ""))
                + (f" <b>(check {_e(check)})</b>" if check else ""),
                _e(r.get("mark", "")),
                _fixed(_num(r.get("dbh_hand_m")) * 100, 1),
                *([_e(r.get("in_plot", ""))] if in_plot else []),
            ]
        )
    head = [
        "Tree",
        "x, y, z (m)",
        "Height m",
        "DBH cm",
        "Crown m",
        "Seen from",
        "Mark",
        "Your DBH cm",
        *(["In the plot"] if in_plot else []),
    ]
    return "<h2>Trees</h2>" + _flags() + html_table(head, body)


def _flags() -> str:
    """Say what the DBH and height flags mean, by the defaults the inventory used."""
    from amrst.plot.flags import DBH_CHECK, DBH_OK, HEIGHT_FLAGS

    heights = "; ".join(
        f"<b>{flag}</b>: {_e(text)}" for flag, text in HEIGHT_FLAGS.items()
    )
    return (
        f"<p>DBH <b>ok</b>: {_e(DBH_OK)}; <b>check</b>: {_e(DBH_CHECK)}; <b>none</b>: "
        f"no DBH. Height {heights}. Lorey's mean height counts the trees with a DBH "
        "and a height flagged ok.</p>"
    )


def _num(value: Any) -> float:
    try:
        return float(value)
    except (TypeError, ValueError):
        return float("nan")


def _fixed(value: Any, digits: int) -> str:
    v = _num(value)
    return "–" if not np.isfinite(v) else f"{v:.{digits}f}"


def _cm(value: float) -> str:
    return "–" if not np.isfinite(value) else f"{100 * value:.1f} cm"


def _pct(value: Any) -> str:
    v = _num(value)
    return "–" if not np.isfinite(v) else f"{v:.0%}"


def _e(value: object) -> str:
    import html

    return html.escape(str(value))
