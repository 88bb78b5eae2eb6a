"""What the Campaign dock's table shows for a tree: its cells and whether it is hidden.

Pure functions of a row of :func:`amrst.campaign.table.campaign_rows` (plus the
``state`` the dock gives it); no Qt.
"""

from __future__ import annotations

from typing import Any

COLUMNS = ("Tree", "State", "Conf.", "Links", "NN-RMSE cm", "TH m", "DBH cm")
NEEDS_PERSON = ("needs review", "failed", "out of date")


def fmt(value: Any, scale: float = 1.0, digits: int = 2) -> str:
    """A number scaled and rounded for a cell; "" for a missing one."""
    if value in ("", None):
        return ""
    try:
        return f"{float(value) * scale:.{digits}f}"
    except (TypeError, ValueError):
        return str(value)


def row_cells(row: dict[str, Any]) -> tuple[str, ...]:
    """The texts of one tree's row, in COLUMNS order."""
    links = (
        f"{row['links_verified']}/{row['links_total']}"
        if row["links_total"] != ""
        else ""
    )
    return (
        row["tree_id"],
        row["state"],
        fmt(row["confidence"], 100, 0)
        + ("%" if row["confidence"] not in ("", None) else ""),
        links,
        fmt(row["NN_RMSE_m"], 100, 1),
        fmt(row["TH"], 1, 1),
        fmt(row["DBH"], 100, 1),
    )


def row_hidden(row: dict[str, Any], text: str, needs_person: bool) -> bool:
    """Whether the filter hides a row: ``text`` in neither id nor state, or not one
    needing a person when only those are asked for."""
    text = text.strip().lower()
    hide = (
        bool(text) and text not in row["tree_id"].lower() and text not in row["state"]
    )
    return hide or (needs_person and row["state"] not in NEEDS_PERSON)


class BatchTracker:
    """Which trees of a running batch wait and which run.

    A tree is *queued* from submission until a Dask worker starts it, then
    *running* until it ends: its worker says so, or the batch has its result,
    whichever comes first.
    """

    def __init__(self) -> None:
        self.queued: set[str] = set()  # submitted, not started on a worker
        self.running: set[str] = set()  # started on a worker, not finished

    def submit(self, tree_ids: set[str]) -> None:
        """A new batch: these trees wait for a worker."""
        self.queued, self.running = set(tree_ids), set()

    def clear(self) -> None:
        """The batch is over (done, failed or cancelled)."""
        self.queued, self.running = set(), set()

    def state(self, state: str, tree_id: str) -> str:
        """The state to list for a tree whose folder says ``state``."""
        from amrst.campaign.review import batch_state

        return batch_state(state, tree_id, self.queued, self.running)

    def start(self, tree_id: str) -> None:
        """A worker started the tree (not when its result came first)."""
        if tree_id in self.queued:
            self.queued.discard(tree_id)
            self.running.add(tree_id)

    def end(self, tree_id: str) -> bool:
        """The tree ended; True the first time it is said (its row is read again)."""
        pending = tree_id in self.queued or tree_id in self.running
        self.queued.discard(tree_id)
        self.running.discard(tree_id)
        return pending
