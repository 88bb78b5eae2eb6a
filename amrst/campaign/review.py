"""A person's review of a campaign: decisions written at once, undone, and the export.

The decision on a tree (``accepted`` or ``rejected``) is written to
``results/<id>/review.json`` the moment it is made (atomically), so a crash loses
nothing, and can be cleared again (the tree is back to its batch state). Accepting a
tree the batch did not register (failed, needs review) takes an explicit
confirmation. :func:`review_state` combines the decision with the batch's results into
the state the app lists: the decision when one was made, else the registration's
(registered, needs review, failed) or not run. :func:`export_tree` writes a tree's
merged cloud (``scan_id`` per point) from its stored transforms without registering
again; :func:`export_accepted` does so for every accepted tree and returns the paths.
"""

from __future__ import annotations

import datetime as _dt
from typing import TYPE_CHECKING

# The decisions and their file are part of this module's interface (the app's).
from amrst.campaign.folder import ACCEPTED as ACCEPTED
from amrst.campaign.folder import DECISIONS as DECISIONS
from amrst.campaign.folder import REJECTED as REJECTED
from amrst.campaign.folder import REVIEW as REVIEW
from amrst.campaign.folder import decision_of as decision_of
from amrst.campaign.folder import has_result, of_other_scans, read_doc, result_run
from amrst.campaign.table import OUT_OF_DATE
from amrst.errors import AmrstError, InvalidInput
from amrst.review.verdict import FAILED, REGISTERED

if TYPE_CHECKING:
    from collections.abc import Sequence
    from pathlib import Path
    from typing import Any

    from amrst.campaign.manifest import Campaign, TreeEntry
    from amrst.progress import Reporter
    from amrst.types import Transform

#: Given to :func:`decide` instead of a decision: remove the tree's decision.
CLEAR = "clear"
#: States needing a person come first when the app sorts.
STATE_ORDER = (
    "needs review",
    "failed",
    OUT_OF_DATE,
    "registered",
    "running",
    "queued",
    "not run",
    REJECTED,
    ACCEPTED,
)


def review_state(campaign: Campaign, tree_id: str, batch_status: str) -> str:
    """Return the tree's state for the app: the decision when one was made, else the batch's.

    A tree not run, or whose result is of other scans than it lists, has no decision
    to show.
    """
    if batch_status in ("not run", OUT_OF_DATE):
        return batch_status
    return decision_of(campaign, tree_id) or batch_status


def exported_path(campaign: Campaign, tree_id: str) -> Path | None:
    """Return the merged cloud :func:`export_tree` last wrote for a tree, if any."""
    out = campaign.results_dir(tree_id)
    name = (read_doc(out / REVIEW) or {}).get("exported")
    return out / str(name) if name and (out / str(name)).is_file() else None


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


def acceptance_warning(campaign: Campaign, tree_id: str) -> str:
    """Say why accepting a tree needs a confirmation; "" when the batch registered it.

    The app asks with these words before it accepts with ``confirm_unregistered``.
    A tree with no result to accept has nothing to ask about (:func:`decide` refuses
    it in its own words).
    """
    from amrst.campaign.table import tree_row

    if not has_result(campaign.results_dir(tree_id)):
        return ""
    status = tree_row(campaign, campaign.tree(tree_id))["status"]
    if status in (REGISTERED, OUT_OF_DATE):
        return ""
    if status == FAILED:
        return f"Tree {tree_id} failed: no candidate verified, so its pose is a guess."
    return f"Tree {tree_id} needs review: nothing clearly confirms its pose."


def _check_decision(
    campaign: Campaign, tree_id: str, decision: str, confirm_unregistered: bool
) -> None:
    """Refuse, in one line, a decision that cannot be recorded as asked."""
    campaign.tree(tree_id)  # refuses an unknown id
    if decision == CLEAR:
        return
    if not has_result(campaign.results_dir(tree_id)):
        raise InvalidInput(
            f"Tree {tree_id} has no result to {decision[:-2]} yet; run it first."
        )
    from amrst.campaign.table import tree_row

    if tree_row(campaign, campaign.tree(tree_id))["status"] == OUT_OF_DATE:
        raise InvalidInput(
            f"Tree {tree_id}'s result is of other scans than campaign.toml lists now; "
            "run it again first."
        )
    if decision == ACCEPTED and not confirm_unregistered:
        warning = acceptance_warning(campaign, tree_id)
        if warning:
            raise InvalidInput(
                f"{warning} Look at it first; to accept it anyway, confirm "
                "(--confirm-unregistered)."
            )


def decide(
    campaign: Campaign,
    tree_ids: Sequence[str],
    decision: str,
    *,
    confirm_unregistered: bool = False,
) -> list[Path]:
    """Record a decision on trees now, or clear it; then rewrite the campaign table.

    Parameters
    ----------
    campaign : Campaign
    tree_ids : sequence of str
    decision : str
        ``accepted``, ``rejected``, or ``clear`` (:data:`CLEAR`): the tree is back to
        its batch state.
    confirm_unregistered : bool
        Accept trees the batch did not register (failed, needs review); without it
        such a tree is refused with :func:`acceptance_warning`'s words.

    Returns
    -------
    list of Path
        The ``review.json`` of each tree (missing once a cleared one holds nothing).

    Raises
    ------
    InvalidInput
        An unknown decision or tree, a tree with no result, or an unconfirmed
        acceptance; nothing is written then.
    """
    from amrst.campaign.table import tree_row, write_table
    from amrst.files.atomic import write_json_atomic

    if decision not in (*DECISIONS, CLEAR):
        raise InvalidInput(
            f"Unknown decision {decision!r}; choose accepted, rejected or clear."
        )
    for tree_id in tree_ids:
        _check_decision(campaign, tree_id, decision, confirm_unregistered)
    now = _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="seconds")
    written = []
    for tree_id in tree_ids:
        path = campaign.results_dir(tree_id) / REVIEW
        doc = read_doc(path) or {}
        for key in ("decision", "decided_utc", "registration_status", "result_run"):
            doc.pop(key, None)
        if decision != CLEAR:
            status = tree_row(campaign, campaign.tree(tree_id))["status"]
            doc.update(
                decision=decision,
                decided_utc=now,
                registration_status=status,
                result_run=result_run(campaign.results_dir(tree_id)),
            )
        if doc:
            write_json_atomic(path, doc)
        else:
            try:
                path.unlink(missing_ok=True)
            except OSError as exc:
                raise InvalidInput(
                    f"Cannot clear the decision on {tree_id}: {path} cannot be "
                    f"removed ({exc.strerror or exc}); check the folder's permissions."
                ) from exc
        written.append(path)
    write_table(campaign)
    return written


def export_tree(campaign: Campaign, tree_id: str, cloud_format: str = "ply") -> Path:
    """Write ``merged.<fmt>`` of a tree from its stored transforms; return its path."""
    from amrst import io
    from amrst.files.atomic import write_json_atomic
    from amrst.io.scans import read_scans
    from amrst.results.export import merge_posed

    entry = campaign.tree(tree_id)
    out = campaign.results_dir(tree_id)
    summary = read_doc(out / "scans.json")
    if summary is None or not has_result(out):
        raise InvalidInput(f"Tree {tree_id} has no result to export; run it first.")
    _refuse_stale(campaign, entry)
    poses = _stored_poses(summary, len(entry.scans), tree_id)
    clouds = [read_scans(campaign.root / spec)[0] for spec in entry.scans]
    merged = merge_posed(clouds, poses, entry.reference)
    path = out / f"merged.{cloud_format}"
    io.write(path, merged)
    doc = read_doc(out / REVIEW) or {}
    doc["exported_utc"] = _dt.datetime.now(_dt.timezone.utc).isoformat(
        timespec="seconds"
    )
    doc["exported"] = path.name
    write_json_atomic(out / REVIEW, doc)
    return path


def _refuse_stale(campaign: Campaign, entry: TreeEntry) -> None:
    """Refuse a tree whose stored poses are of other scans than it lists now.

    Other scans, in another order, another reference (told from the stamp alone), or
    files with other contents (their hashes compared).
    """
    from amrst.campaign.run import STAMP, tree_inputs

    out = campaign.results_dir(entry.id)
    ran = (read_doc(out / STAMP) or {}).get("inputs")
    if ran is None:  # results of a version that did not record them
        return
    what = "its list of scans or its reference" if of_other_scans(out, entry) else ""
    if not what:
        files = tree_inputs(campaign.root.resolve(), entry)["files"]
        gone = [
            name for name, digest in files.items() if digest.startswith("unreadable:")
        ]
        if gone:
            raise InvalidInput(
                f"Tree {entry.id}: its scan {gone[0]} cannot be read (missing, or no "
                "permission): put it back where the manifest says."
            )
        what = "its scans' contents" if files != ran.get("files") else ""
    if what:
        raise InvalidInput(
            f"Tree {entry.id}'s result is out of date: {what} changed since it ran. "
            f"Run it again (amrst batch DIR --tree {entry.id}), then decide again."
        )


def _stored_poses(
    summary: dict[str, Any], count: int, tree_id: str
) -> list[Transform | None]:
    """Each scan's stored ``T_reference_scan`` (None: not placed), checked."""
    from amrst.types import check_rigid

    try:
        scans = list(summary["scans"])
        if len(scans) != count:
            raise ValueError(f"{len(scans)} scans where the manifest lists {count}")
        return [
            None
            if scan["T_reference_scan"] is None
            else check_rigid(scan["T_reference_scan"], f"scan {k + 1}'s pose")
            for k, scan in enumerate(scans)
        ]
    except (KeyError, TypeError, ValueError, InvalidInput) as exc:
        raise InvalidInput(
            f"Tree {tree_id}'s scans.json cannot be read ({exc}); run it again "
            f"(amrst batch DIR --tree {tree_id} --force)."
        ) from exc


def export_accepted(
    campaign: Campaign, cloud_format: str = "ply", reporter: Reporter | None = None
) -> tuple[list[Path], dict[str, str]]:
    """Export every accepted tree (:func:`export_tree`), with progress a tree.

    ``reporter`` is asked for cancel between trees (each tree's file is written
    whole or not at all).

    Returns
    -------
    list of Path
        The merged clouds written, in manifest order.
    dict
        Tree id -> why its export failed (one line), for the trees that did.
    """
    written: list[Path] = []
    errors: dict[str, str] = {}
    accepted = [e for e in campaign.trees if decision_of(campaign, e.id) == ACCEPTED]
    for k, entry in enumerate(accepted):
        if reporter is not None:
            reporter.check_cancelled()
            reporter.progress(k / len(accepted), f"exporting {entry.id}")
        try:
            written.append(export_tree(campaign, entry.id, cloud_format))
        except AmrstError as exc:
            errors[entry.id] = str(exc)
    return written, errors
