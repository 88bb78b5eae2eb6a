"""How a batch spreads its trees over the workers: longest first, one core per task.

Two rules keep every worker busy until the batch ends:

- **Longest first** (LPT scheduling): in manifest order the biggest trees may come
  last, and one worker would finish them alone while the others wait.
  :func:`longest_first` orders the trees by the seconds they took last time when a
  run is on record, else by the bytes of their scan files.
- **One core per task**: a tree's registration runs on two threads by default
  (``amrst.neighbours.THREADS``), which helps one process on an idle machine but
  oversubscribes the cores when every core already has a worker. :func:`scan_threads`
  gives each task the threads its share of the host's cores allows (1 or 2).
"""

from __future__ import annotations

import os
from typing import TYPE_CHECKING, Any, TypeVar

if TYPE_CHECKING:
    from pathlib import Path

    from amrst.campaign.manifest import Campaign, TreeEntry


def tree_cost(root: Path, entry: TreeEntry) -> int:
    """Return the bytes of a tree's scan files (0 for those that cannot be read).

    A scan that is one of several in a file (``plot.e57#3``) counts the whole file:
    all such trees then tie and keep their manifest order.
    """
    from amrst.io.scans import split_spec

    total = 0
    for spec in entry.scans:
        path, _ = split_spec(root / spec)
        try:
            total += path.stat().st_size
        except OSError:  # reported when the tree runs
            continue
    return total


def seconds_before(out: Path) -> float | None:
    """Return the seconds a tree's last run took (stamp or error), None if unknown."""
    import json

    from amrst.campaign.run import ERROR, STAMP

    for name in (STAMP, ERROR):
        try:
            doc = json.loads((out / name).read_text(encoding="utf-8"))
        except (OSError, ValueError):
            continue
        seconds = doc.get("seconds") if isinstance(doc, dict) else None
        if isinstance(seconds, (int, float)) and seconds > 0:
            return float(seconds)
    return None


def tree_costs(campaign: Campaign, entries: list[TreeEntry]) -> dict[str, float]:
    """Return each tree's expected cost, in seconds when a run is on record.

    A tree run before (``--force``, changed parameters, a failed tree fixed) costs
    what it took then; the others their bytes times the median seconds per byte of
    those (or plain bytes when no tree has a time on record).
    """
    root = campaign.root.resolve()
    size = {e.id: float(tree_cost(root, e)) for e in entries}
    before = {e.id: seconds_before(campaign.results_dir(e.id)) for e in entries}
    rates = sorted(
        t / size[i] for i, t in before.items() if t is not None and size[i] > 0
    )
    if not rates:
        return size
    per_byte = rates[len(rates) // 2]
    return {i: t if t is not None else size[i] * per_byte for i, t in before.items()}


_Stamp = TypeVar("_Stamp")


def longest_first(
    campaign: Campaign, todo: list[tuple[TreeEntry, _Stamp]]
) -> tuple[list[tuple[TreeEntry, _Stamp]], dict[str, float]]:
    """Return ``todo`` (``[(entry, stamp)]``) costliest first, and each tree's cost.

    Ties keep the manifest order (the sort is stable). See :func:`tree_costs`.
    """
    costs = tree_costs(campaign, [entry for entry, _ in todo])
    return sorted(todo, key=lambda item: -costs[item[0].id]), costs


def time_left(
    elapsed: float, done: int, total: int, done_cost: float, total_cost: float
) -> float:
    """Return the seconds left, from the share of the trees' cost done so far.

    Longest first, the count alone would overstate it (the first trees are the
    slowest); by count when no size is known.
    """
    if done_cost > 0 and total_cost >= done_cost:
        return elapsed * (total_cost - done_cost) / done_cost
    return elapsed / max(done, 1) * (total - done)


def host_cores() -> int:
    """Return the cores this process may run on."""
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:  # macOS, Windows
        return os.cpu_count() or 1


def scan_threads(cores: int, tasks: int) -> int:
    """Return the threads of one tree task when ``tasks`` run at once on ``cores``.

    Parameters
    ----------
    cores : int
        Cores of the host.
    tasks : int
        Tree tasks that run at once on it (worker processes x threads each).

    Returns
    -------
    int
        2 when every task has two cores to itself, else 1.
    """
    return 2 if cores >= 2 * max(tasks, 1) else 1


def cluster_scan_threads(client: Any) -> int:
    """Return :func:`scan_threads` for the most loaded host of a Dask cluster."""
    workers = client.scheduler_info().get("workers", {})
    if not workers:
        return 1
    cores = client.run(host_cores)  # {worker address: cores of its host}
    per_host: dict[str, list[int]] = {}
    for address, info in workers.items():
        per_host.setdefault(str(info.get("host", address)), []).append(
            int(info.get("nthreads", 1))
        )
    host_of = {a: str(i.get("host", a)) for a, i in workers.items()}
    host_cores_ = {host_of[a]: int(n) for a, n in cores.items() if a in host_of}
    return min(
        scan_threads(host_cores_.get(host, 1), sum(threads))
        for host, threads in per_host.items()
    )
