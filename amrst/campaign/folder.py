"""What a tree's results folder holds: its JSON documents and the decision on it.

The table, the stored results and the review all read these; they live here so none
of those modules needs another to read a file.
"""

from __future__ import annotations

import json
from typing import TYPE_CHECKING, Any

from amrst.campaign.run import ERROR, STAMP

if TYPE_CHECKING:
    from pathlib import Path

    from amrst.campaign.manifest import Campaign

REVIEW = "review.json"
ACCEPTED = "accepted"
REJECTED = "rejected"
DECISIONS = (ACCEPTED, REJECTED)


def read_doc(path: Path) -> dict[str, Any] | None:
    """Return a result folder's JSON object (None: missing, unreadable or not one)."""
    try:
        doc = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return None
    return doc if isinstance(doc, dict) else None


def decision_of(campaign: Campaign, tree_id: str) -> str:
    """Return the decision on a tree's result: accepted, rejected, or "" (none).

    A decision holds for the result it was made on (``result_run``, the run that
    made it): a tree run again, or whose last run ended in an error, has none.
    """
    out = campaign.results_dir(tree_id)
    if (out / ERROR).is_file():
        return ""
    review = read_doc(out / REVIEW) or {}
    if review.get("result_run") != result_run(out):  # None == None: older files
        return ""
    decision = str(review.get("decision", ""))
    return decision if decision in DECISIONS else ""


def result_run(out: Path) -> str | None:
    """Return the id of the run whose result ``out`` holds (None: none recorded)."""
    run = (read_doc(out / STAMP) or {}).get("run")
    return run if isinstance(run, str) else None
