"""The campaign table: one row per tree, read back from the results on disk.

Column names follow what 3DFin and TreeQSM users read: ``TH`` (total height, m),
``DBH`` (diameter at breast height, m), ``X``, ``Y`` (stem position, world
coordinates). The table is rebuilt from every tree's ``scans.json``, ``stamp.json``,
``error.json`` and ``review.json``, so it is the same whichever run (or resumed run)
produced them. ``status`` is the registration's state (registered, needs review,
failed; or not run), ``decision`` the technician's (accepted, rejected, or empty).
"""

from __future__ import annotations

import csv
import io as _stdio
import math
from typing import TYPE_CHECKING, Any

from amrst.campaign.folder import (
    decision_of,
    of_other_scans,
    read_doc,
    scans_changed,
)
from amrst.campaign.run import ERROR, STAMP

if TYPE_CHECKING:
    from pathlib import Path

    from amrst.campaign.manifest import Campaign, TreeEntry

#: The state of a tree whose manifest lists other scans (or another reference)
#: than its result was found for: run it again.
OUT_OF_DATE = "out of date"
COLUMNS = (
    "tree_id",
    "status",
    "decision",
    "confidence",
    "n_scans",
    "n_reached",
    "links_verified",
    "links_total",
    "NN_RMSE_m",
    "overlap",
    "TH",
    "DBH",
    "crown_width_m",
    "crown_area_m2",
    "X",
    "Y",
    "reference",
    "seconds",
    "cpu_seconds",
    "finished_utc",
    "error",
)
TABLE = "campaign.csv"
TABLE_XLSX = "campaign.xlsx"


def _num(value: Any) -> float | str:
    if value is None:
        return ""
    try:
        v = float(value)
    except (TypeError, ValueError):
        return ""
    return "" if math.isnan(v) else v


def tree_row(campaign: Campaign, entry: TreeEntry) -> dict[str, Any]:
    """Return one tree's row from its results folder (``not run`` when empty)."""
    out = campaign.results_dir(entry.id)
    row: dict[str, Any] = dict.fromkeys(COLUMNS, "")
    row.update(
        tree_id=entry.id,
        n_scans=len(entry.scans),
        reference=entry.scans[entry.reference],
    )
    if entry.stem is not None:
        row["X"], row["Y"] = entry.stem
    stamp, error = read_doc(out / STAMP), read_doc(out / ERROR)
    summary = read_doc(out / "scans.json") if stamp else None
    if error is not None:
        row.update(
            status="failed",
            error=error.get("error", ""),
            seconds=_num(error.get("seconds")),
            finished_utc=error.get("finished_utc", ""),
        )
        return row
    if stamp is None or summary is None:
        row["status"] = "not run"
        return row
    if of_other_scans(out, entry) or scans_changed(campaign.root.resolve(), out):
        row["status"] = OUT_OF_DATE  # the result is of the scans it had
        return row
    from amrst.campaign.stored import summary_status

    merged = summary.get("tree", {}).get("merged", {})
    row.update(
        status=summary_status(summary, out),
        decision=decision_of(campaign, entry.id),
        confidence=_num(summary.get("confidence")),
        n_reached=summary.get("n_reached", ""),
        links_verified=summary.get("links_verified", ""),
        links_total=summary.get("links_total", ""),
        NN_RMSE_m=_num(summary.get("rmse_overlap_m")),
        overlap=_num(summary.get("overlap_fraction")),
        TH=_num(merged.get("height_m")),
        DBH=_num(merged.get("dbh_m")),
        crown_width_m=_num(merged.get("crown_width_m")),
        crown_area_m2=_num(merged.get("crown_area_m2")),
        seconds=_num(stamp.get("seconds")),
        cpu_seconds=_num(stamp.get("cpu_seconds")),
        finished_utc=stamp.get("finished_utc", ""),
    )
    if merged.get("stem_x_m") is not None:
        row["X"], row["Y"] = _num(merged["stem_x_m"]), _num(merged["stem_y_m"])
    return row


def campaign_rows(campaign: Campaign) -> list[dict[str, Any]]:
    """Return every tree's row, in manifest order."""
    return [tree_row(campaign, t) for t in campaign.trees]


def write_table(
    campaign: Campaign, rows: list[dict[str, Any]] | None = None
) -> list[Path]:
    """Write campaign.csv (and .xlsx when openpyxl is installed), atomically."""
    from amrst.files.atomic import write_atomic, write_text_atomic, xlsx_book

    rows = campaign_rows(campaign) if rows is None else rows
    buf = _stdio.StringIO()
    writer = csv.DictWriter(buf, fieldnames=COLUMNS)
    writer.writeheader()
    writer.writerows(rows)
    written = [campaign.root / TABLE]
    write_text_atomic(written[0], buf.getvalue())
    from amrst import __version__

    book = xlsx_book("trees", COLUMNS, rows, f"AMRST {__version__}")
    if book is None:
        return written
    write_atomic(campaign.root / TABLE_XLSX, lambda tmp: book.save(tmp))
    written.append(campaign.root / TABLE_XLSX)
    return written
