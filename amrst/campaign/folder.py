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

    from amrst.campaign.manifest import Campaign, TreeEntry

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


def has_result(out: Path) -> bool:
    """Tell whether a tree's results folder holds a finished run's result.

    Its stamp is written last, and removed when a run starts, so a run cancelled or
    killed leaves none; a run that ended in an error leaves ``error.json``.
    """
    return (
        (out / STAMP).is_file()
        and (out / "scans.json").is_file()
        and not (out / ERROR).is_file()
    )


def of_other_scans(out: Path, entry: TreeEntry) -> bool:
    """Tell whether the result in ``out`` is of other scans than ``entry`` lists now.

    Other scans, another order or another reference; older stamps, which do not
    record them, are taken as of these.
    """
    ran = (read_doc(out / STAMP) or {}).get("inputs")
    return isinstance(ran, dict) and (
        ran.get("scans") != list(entry.scans) or ran.get("reference") != entry.reference
    )


def scans_changed(root: Path, out: Path) -> bool:
    """Tell whether a scan file was replaced since the result in ``out`` ran.

    Its size is compared with the stamp's: no file is read, so every status shown
    can ask. A scan rewritten at the same size is found by the export, which hashes
    the files. A result of a version that did not record sizes is taken as of these
    files.
    """
    from pathlib import Path

    sizes = (read_doc(out / STAMP) or {}).get("scan_sizes")
    if not isinstance(sizes, dict):
        return False
    for name, size in sizes.items():
        path = Path(name) if Path(name).is_absolute() else root / name
        try:
            now = path.stat().st_size
        except OSError:
            now = -1
        if now != size:
            return True
    return False


def decision_of(campaign: Campaign, tree_id: str) -> str:
    """Return the decision on a tree's result: accepted, rejected, or "" (none).

    A decision holds for the result it was made on (``result_run``, the run that
    made it): a tree run again, or whose last run ended in an error, has none.
    """
    out = campaign.results_dir(tree_id)
    if not has_result(out):
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
