"""A person's review of a campaign: decisions written at once, and the export.

The decision on a tree (``accepted``, ``rejected``) is written to
``results/<id>/review.json`` the moment it is made (atomically), so a crash loses
nothing. :func:`review_state` combines it with the batch's results into the state the
app lists: not run, registered, needs review, failed, accepted, exported.
:func:`export_tree` writes a tree's merged cloud (``scan_id`` per point) from its stored
transforms without registering again.
"""

from __future__ import annotations

import datetime as _dt
from typing import TYPE_CHECKING

import numpy as np

from amrst.campaign.table import read_doc
from amrst.errors import InvalidInput

if TYPE_CHECKING:
    from pathlib import Path

    from amrst.campaign.manifest import Campaign

REVIEW = "review.json"
DECISIONS = ("accepted", "rejected")
#: States needing a person come first when the app sorts.
STATE_ORDER = (
    "needs review",
    "failed",
    "registered",
    "running",
    "queued",
    "not run",
    "rejected",
    "accepted",
    "exported",
)


def review_state(campaign: Campaign, tree_id: str, batch_status: str) -> str:
    """Return the tree's state for the app: the decision when one was made, else the batch's."""
    doc = read_doc(campaign.results_dir(tree_id) / REVIEW)
    if doc is None or batch_status in ("not run", "failed"):
        return batch_status
    if doc.get("exported_utc"):
        return "exported"
    decision = str(doc.get("decision", ""))
    return decision if decision in DECISIONS else batch_status


def batch_state(state: str, tree_id: str, queued: set[str], running: set[str]) -> str:
    """Return the state to list while a batch runs.

    ``running`` only for a tree a worker has started, ``queued`` for one submitted
    and waiting; a tree in neither set (finished, or never submitted) keeps ``state``
    (read from the folder).
    """
    if tree_id in running:
        return "running"
    if tree_id in queued:
        return "queued"
    return state


def set_decision(campaign: Campaign, tree_id: str, decision: str) -> Path:
    """Record a decision on a tree now (atomic write); return the file written."""
    from amrst.files.atomic import write_json_atomic

    if decision not in DECISIONS:
        raise InvalidInput(f"Unknown decision {decision!r}; choose one of {DECISIONS}.")
    campaign.tree(tree_id)  # refuses an unknown id
    out = campaign.results_dir(tree_id)
    if not (out / "scans.json").is_file():
        raise InvalidInput(
            f"Tree {tree_id} has no result to {decision[:-2]} yet; run it first."
        )
    now = _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="seconds")
    write_json_atomic(out / REVIEW, {"decision": decision, "decided_utc": now})
    return out / REVIEW


def export_tree(campaign: Campaign, tree_id: str, cloud_format: str = "ply") -> Path:
    """Write ``merged.<fmt>`` of a tree from its stored transforms; mark it exported."""
    from amrst import io
    from amrst.files.atomic import write_json_atomic
    from amrst.io.scans import read_scans
    from amrst.multiscan.export import merge_moved
    from amrst.types import Cloud, transform_cloud

    entry = campaign.tree(tree_id)
    out = campaign.results_dir(tree_id)
    summary = read_doc(out / "scans.json")
    if summary is None:
        raise InvalidInput(f"Tree {tree_id} has no result to export; run it first.")
    clouds = [read_scans(campaign.root / spec)[0] for spec in entry.scans]
    ref = clouds[entry.reference]
    moved: list[tuple[int, Cloud]] = []
    for k, scan in enumerate(summary["scans"]):
        if scan["T_reference_scan"] is not None:
            T = np.asarray(scan["T_reference_scan"], float)
            moved.append((k, transform_cloud(T, clouds[k], ref.offset)))
    merged = merge_moved(ref, moved)
    path = out / f"merged.{cloud_format}"
    io.write(path, merged)
    doc = read_doc(out / REVIEW) or {}
    doc["exported_utc"] = _dt.datetime.now(_dt.timezone.utc).isoformat(
        timespec="seconds"
    )
    doc["exported"] = path.name
    write_json_atomic(out / REVIEW, doc)
    return path
