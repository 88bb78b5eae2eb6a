"""Run every pending tree of a campaign as a Dask task.

The same code runs on a :class:`distributed.LocalCluster` of worker processes (the
default: ``workers`` processes, one thread each) and on an existing ``dask.distributed``
scheduler given by address (workers started with ``dask worker ADDRESS`` on machines
that see the campaign folder at the same path). Trees whose stamp matches are skipped;
the others are submitted. A finished tree's results are on disk, its stamp written
last, and the campaign table is rewritten at most once a second while trees finish and
once at the end, so a batch killed at any moment loses only the trees in flight.

Trees go longest first, each with the threads its share of the cores allows, on
workers that imported what a tree needs before the first one (``amrst.campaign.plan``).
A local cluster gives each worker one task at a time (``worker-saturation`` 1.0) so
that order holds to the end, and leaves glibc's memory trimming as ``amrst register``
has it; an external cluster keeps its own settings (for the same, start the scheduler
with ``DASK_DISTRIBUTED__SCHEDULER__WORKER_SATURATION=1.0`` and the workers with
``DASK_DISTRIBUTED__NANNY__PRE_SPAWN_ENVIRON__MALLOC_TRIM_THRESHOLD_=None``).
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, Protocol

from amrst.campaign.manifest import RESULTS
from amrst.campaign.plan import (
    cluster_scan_threads,
    host_cores,
    longest_first,
    time_left,
)
from amrst.campaign.run import (
    TREE_TOPIC,
    TreeStamp,
    is_done,
    run_tree,
    tree_stamp,
    warm_worker,
)
from amrst.campaign.table import campaign_rows, tree_row, write_table
from amrst.files.atomic import make_folder

if TYPE_CHECKING:
    from collections.abc import Callable, Iterator

    from amrst.campaign.manifest import Campaign, TreeEntry
    from amrst.params import RegistrationParams

TABLE_EVERY_S = 1.0  # campaign.csv/.xlsx rewritten at most this often while trees end
WAIT_S = 0.2  # how often a batch waiting for its trees looks at Cancel


class BatchProgress(Protocol):
    """What the batch tells as it goes (the CLI draws a bar, the app updates rows)."""

    def update(
        self,
        done: int,
        errors: int,
        running: int,
        total: int,
        left_s: float | None,
        row: dict[str, Any] | None,
    ) -> None:
        """Report the counts after a change; ``row`` is the tree just finished.

        ``done``: trees with a result (whatever its state), skipped ones included;
        ``errors``: trees that ended without one.
        """

    def check_cancelled(self) -> None:
        """Raise ``Cancelled`` when the batch is to stop (asked while trees run)."""


@dataclass
class BatchSummary:
    """What one batch run did: trees skipped (already done), run to a result, errors.

    ``finished`` trees have a result, whose state (registered, needs review, failed)
    ``statuses`` gives; ``errors`` holds the trees that ended without one (a file that
    cannot be read, a worker that died), with the one-line reason.
    """

    skipped: list[str] = field(default_factory=list)
    finished: list[str] = field(default_factory=list)
    errors: dict[str, str] = field(default_factory=dict)
    statuses: dict[str, str] = field(default_factory=dict)
    seconds: float = 0.0  # wall time of the whole call, cluster start included
    workers: int = 0
    results: list[dict[str, Any]] = field(default_factory=list)

    def counts(self) -> str:
        """Say what the trees of this run came to, in the states' words.

        ``"2 registered, 1 needs review, 1 failed (1 with an error), 3 already done"``:
        a tree that ended in an error counts as failed.
        """
        from amrst.review.verdict import FAILED, STATUSES

        n = dict.fromkeys(STATUSES, 0)
        for status in self.statuses.values():
            n[status] = n.get(status, 0) + 1
        n[FAILED] += len(self.errors)
        parts = [f"{count} {status}" for status, count in n.items()]
        if self.errors:
            parts[-1] += f" ({len(self.errors)} with an error)"
        return ", ".join([*parts, f"{len(self.skipped)} already done"])


def _params(
    campaign: Campaign, params: RegistrationParams | None
) -> RegistrationParams:
    from amrst.params import RegistrationParams, load_params, load_preset

    if params is not None:
        return params
    if campaign.params:
        return load_params(campaign.root / campaign.params)
    if campaign.preset:
        return load_preset(campaign.preset)
    return RegistrationParams()


def pending_trees(
    campaign: Campaign,
    params: RegistrationParams | None = None,
    force: bool = False,
    clouds: str = "",
) -> tuple[list[tuple[Any, TreeStamp]], list[str], dict[str, Any]]:
    """Return ``([(entry, stamp)] to run, [ids already done], params dict)``."""
    from amrst.params import params_to_dict

    doc = params_to_dict(_params(campaign, params))
    todo, done = [], []
    root = campaign.root.resolve()
    for entry in campaign.trees:
        stamp = tree_stamp(root, entry, doc, clouds)
        if not force and is_done(campaign.results_dir(entry.id), stamp.digest):
            done.append(entry.id)
        else:
            todo.append((entry, stamp))
    return todo, done, doc


def _client(workers: int, scheduler: str | None) -> tuple[Any, Any]:
    import logging

    from distributed import Client, LocalCluster  # untyped: Any here

    # The scheduler of a local cluster runs in this process: its INFO lines would
    # drown the progress bar (the workers get silence_logs).
    for name in ("distributed", "distributed.scheduler", "distributed.nanny"):
        logging.getLogger(name).setLevel(logging.WARNING)

    import dask

    client_cls: Any = Client
    cluster_cls: Any = LocalCluster

    if scheduler:
        try:
            return client_cls(scheduler, timeout="20s"), None
        except (OSError, ValueError, TimeoutError) as exc:
            from amrst.errors import InvalidInput

            raise InvalidInput(
                f"No Dask scheduler answers at {scheduler!r} ({exc}): give its "
                "address as tcp://HOST:PORT, and check that it runs and this machine "
                "reaches it."
            ) from exc
    config = {
        # One task per worker thread, the rest queued on the scheduler (Dask's default,
        # 1.1, gives a 1-thread worker a second task to hold): the longest-first order
        # is then kept to the end, and no tree waits behind another on a busy worker.
        "distributed.scheduler.worker-saturation": 1.0,
        # Dask's nanny sets MALLOC_TRIM_THRESHOLD_=65536 in its workers: glibc then
        # hands freed memory back at once and faults it in again, which costs CPU on
        # every tree; glibc's default keeps a tree's CPU what amrst register uses.
        "distributed.nanny.pre-spawn-environ.MALLOC_TRIM_THRESHOLD_": None,
        # The dashboard's profiler samples every task's stack, which costs CPU, and a
        # batch never shows it.
        "distributed.worker.profile.enabled": False,
    }
    with dask.config.set(config):
        cluster = cluster_cls(
            n_workers=workers,
            threads_per_worker=1,
            processes=True,
            dashboard_address=":0",  # any free port: never clashes with another batch
            silence_logs=40,  # logging.ERROR: the progress bar is the output
        )
    return client_cls(cluster), cluster


#: Local workers by default: two, or one on a one-core machine.
DEFAULT_WORKERS = min(2, host_cores())


def run_batch(
    campaign: Campaign,
    *,
    workers: int = DEFAULT_WORKERS,
    scheduler: str | None = None,
    params: RegistrationParams | None = None,
    force: bool = False,
    progress: BatchProgress | None = None,
    only: list[str] | None = None,
    clouds: str = "",
    on_worker_event: Callable[[str, str], None] | None = None,
    threads_per_tree: int | None = None,
) -> BatchSummary:
    """Register every tree not done yet; write the table after each one.

    Parameters
    ----------
    campaign : Campaign
    workers : int
        Worker processes of the local cluster (ignored with ``scheduler``).
    scheduler : str or None
        Address of a running ``dask scheduler`` (``tcp://host:8786``).
    params : RegistrationParams or None
        Default: the manifest's ``params`` / ``preset``, else the defaults.
    force : bool
        Run every tree, done or not.
    progress : BatchProgress or None
    only : list of str or None
        Tree ids to consider (default: all).
    clouds : str
        Also write each tree's merged cloud in this format ("" = none).
    on_worker_event : callable or None
        Called as ``(tree id, "started" | "finished")`` when a worker starts or ends a
        tree (Dask worker events, from the client's thread), so "running" can mean
        running, not submitted.
    threads_per_tree : int or None
        Threads each tree's registration uses (its two scans' analysis and the
        KD-tree queries). None: 2 when every worker of a host has two cores to
        itself, else 1 (:func:`amrst.campaign.plan.cluster_scan_threads`).

    Returns
    -------
    BatchSummary
    """
    t0 = time.perf_counter()
    # Checked first: a wrong option is wrong even with every tree done.
    _check_options(workers, scheduler, threads_per_tree)
    todo, done, doc = _select(campaign, params, force, clouds, only)
    summary = BatchSummary(skipped=done)
    total = len(todo) + len(done)
    if not todo:
        write_table(campaign)
        if progress is not None:
            progress.update(len(done), 0, 0, total, 0.0, None)
        return summary
    make_folder(campaign.root / RESULTS, "results folder")  # each tree's goes in it
    todo, costs = longest_first(campaign, todo)
    rows = campaign_rows(campaign)  # the table, each row replaced as its tree ends
    client, cluster = _client(workers, scheduler)
    try:
        summary.workers = len(client.scheduler_info().get("workers", {})) or workers
        if on_worker_event is not None:
            tell = on_worker_event
            client.subscribe_topic(
                TREE_TOPIC, lambda ev: tell(ev[1]["id"], ev[1]["event"])
            )
        client.run(warm_worker)  # imports on every worker at once, not in a tree
        threads = threads_per_tree or cluster_scan_threads(client)
        futures = _submit(client, campaign, todo, doc, clouds, threads)
        _collect(
            futures,
            campaign=campaign,
            todo=todo,
            costs=costs,
            rows=rows,
            summary=summary,
            progress=progress,
        )
    finally:
        client.close()
        if cluster is not None:
            cluster.close()
    summary.seconds = time.perf_counter() - t0
    return summary


def _select(
    campaign: Campaign,
    params: RegistrationParams | None,
    force: bool,
    clouds: str,
    only: list[str] | None,
) -> tuple[list[tuple[TreeEntry, TreeStamp]], list[str], dict[str, Any]]:
    """Return the trees to run (with stamps), the ids done, and the parameters' doc.

    ``only`` keeps those tree ids; an id the campaign does not have is refused.
    """
    from amrst.errors import InvalidInput

    todo, done, doc = pending_trees(campaign, params, force, clouds)
    if only is not None:
        unknown = set(only) - {t.id for t in campaign.trees}
        if unknown:
            raise InvalidInput(f"No tree {sorted(unknown)[0]!r} in the campaign.")
        todo = [(e, s) for e, s in todo if e.id in only]
        done = [i for i in done if i in only]
    return todo, done, doc


def _check_options(
    workers: int, scheduler: str | None, threads_per_tree: int | None
) -> None:
    """Refuse a worker count or a thread count out of range, in one line."""
    from amrst.errors import InvalidInput

    cores = host_cores()
    if not scheduler and not 1 <= workers <= cores:
        # Each worker registers trees with 1-2 threads: more than the cores only
        # share them, each with a tree's scans in memory.
        raise InvalidInput(
            f"--workers must be 1 to {cores} (this machine's cores), got {workers}."
        )
    if threads_per_tree is not None and not 1 <= threads_per_tree <= 2:
        raise InvalidInput(
            f"--threads-per-tree must be 1 or 2, got {threads_per_tree}."
        )


def _task_key(entry: TreeEntry, stamp: TreeStamp) -> str:
    return f"amrst-tree-{entry.id}-{stamp.digest[:12]}"


def _submit(
    client: Any,
    campaign: Campaign,
    todo: list[tuple[TreeEntry, TreeStamp]],
    doc: dict[str, Any],
    clouds: str,
    threads: int,
) -> list[Any]:
    """Submit one task per tree, the first of ``todo`` with the highest priority."""
    root = str(campaign.root.resolve())
    return [
        client.submit(
            run_tree,
            root,
            entry,
            doc,
            stamp,
            clouds,
            threads,
            key=_task_key(entry, stamp),
            pure=False,
            priority=len(todo) - k,  # longest first
        )
        for k, (entry, stamp) in enumerate(todo)
    ]


def _row_of(future: Any, todo: list[tuple[TreeEntry, TreeStamp]]) -> dict[str, Any]:
    """Return a finished task's row, or a failed row when its worker died."""
    try:
        row: dict[str, Any] = future.result()
    except Exception as exc:  # the worker died (KilledWorker) or similar
        key = str(future.key)
        tree_id = next((e.id for e, s in todo if key == _task_key(e, s)), key)
        return {"id": tree_id, "ok": False, "error": f"{type(exc).__name__}: {exc}"}
    return row


def _as_they_end(futures: list[Any], progress: BatchProgress | None) -> Iterator[Any]:
    """Yield each tree's future as it ends.

    While none has, ``progress`` is asked for a cancel every ``WAIT_S``: a tree can
    take minutes, and Cancel (or closing the app) must not wait for it. The caller
    then closes the client (and a local cluster, which stops the trees in flight; on
    a remote scheduler those run to their end).
    """
    from distributed import as_completed as _as_completed

    as_completed: Any = _as_completed  # untyped
    ended = as_completed(futures)
    while not ended.is_empty():
        if ended.has_ready():
            yield from ended.next_batch(block=False)
            continue
        check = getattr(progress, "check_cancelled", None)  # a caller's may lack it
        if check is not None:
            check()
        time.sleep(WAIT_S)


def _collect(
    futures: list[Any],
    *,
    campaign: Campaign,
    todo: list[tuple[TreeEntry, TreeStamp]],
    costs: dict[str, float],
    rows: list[dict[str, Any]],
    summary: BatchSummary,
    progress: BatchProgress | None,
) -> None:
    """Record each tree as it ends: in ``summary``, the table and the progress."""
    done = len(summary.skipped)
    total = len(todo) + done
    total_cost, done_cost = sum(costs.values()), 0.0
    index = {entry.id: k for k, entry in enumerate(campaign.trees)}
    started = time.perf_counter()
    if progress is not None:
        progress.update(done, 0, min(len(todo), summary.workers), total, None, None)
    written = time.perf_counter()
    for finished, future in enumerate(_as_they_end(futures, progress), start=1):
        row = _row_of(future, todo)
        summary.results.append(row)
        if row.get("ok"):
            summary.finished.append(row["id"])
            summary.statuses[row["id"]] = str(row.get("status", ""))
        else:
            summary.errors[row["id"]] = row.get("error", "")
        # The table as trees end (each row read back from its results folder), at
        # most once a second, so that writing it takes no noticeable CPU from the
        # workers. Nothing is lost by the wait: every tree's results are on disk and
        # the table is rebuilt from them on the next run.
        if row["id"] in index:
            k = index[row["id"]]
            rows[k] = tree_row(campaign, campaign.trees[k])
        if finished == len(todo):  # read afresh: decisions made while it ran
            write_table(campaign)
        elif time.perf_counter() - written >= TABLE_EVERY_S:
            write_table(campaign, rows)
            written = time.perf_counter()
        done_cost += costs.get(row["id"], 0.0)
        if progress is not None:
            left = time_left(
                time.perf_counter() - started,
                finished,
                len(todo),
                done_cost,
                total_cost,
            )
            running = min(len(todo) - finished, summary.workers)
            progress.update(
                done + len(summary.finished),
                len(summary.errors),
                running,
                total,
                left,
                row,
            )
