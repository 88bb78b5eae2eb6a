"""The batch's worker events: a tree is running from its start to its end on a worker.

A real Dask LocalCluster (processes) with one worker: the events come in order,
started then finished for each tree, never two trees open at once; a tree run outside
Dask runs as before.
"""

from __future__ import annotations

import shutil
import threading

import pytest

from amrst.campaign import init_campaign, run_batch


@pytest.mark.slow
def test_one_worker_runs_one_tree_at_a_time(tmp_path, sample_pair):
    for tree in ("T01", "T02"):
        (tmp_path / tree).mkdir()
        for path in (sample_pair.target_path, sample_pair.source_path):
            shutil.copy(path, tmp_path / tree / path.name)
    campaign, _ = init_campaign(tmp_path)
    events: list[tuple[str, str]] = []
    lock = threading.Lock()

    def record(tree_id: str, event: str) -> None:
        with lock:  # called from the Dask client's thread
            events.append((tree_id, event))

    summary = run_batch(campaign, workers=1, on_worker_event=record)
    assert sorted(summary.finished) == ["T01", "T02"]
    open_trees: set[str] = set()
    for tree_id, event in events:
        if event == "started":
            assert not open_trees, events  # one worker: one tree at a time
            open_trees.add(tree_id)
        else:
            assert open_trees == {tree_id}, events
            open_trees.clear()
    assert sorted(events) == sorted(
        (t, e) for t in ("T01", "T02") for e in ("started", "finished")
    )


def _one_tree(root, sample_pair):
    """A campaign of one tree, T01, the sample pair: ``run_tree``'s arguments."""
    from amrst.campaign import load_campaign
    from amrst.campaign.batch import pending_trees

    (root / "T01").mkdir()
    for path in (sample_pair.target_path, sample_pair.source_path):
        shutil.copy(path, root / "T01" / path.name)
    init_campaign(root)
    todo, _, doc = pending_trees(load_campaign(root))
    entry, stamp = todo[0]
    return str(root), entry, doc, stamp


def test_a_tree_run_outside_dask_still_runs(tmp_path, sample_pair):
    # no Dask worker to tell (get_worker fails): the tree runs and reports as ever
    from amrst.campaign.run import run_tree

    row = run_tree(*_one_tree(tmp_path, sample_pair))
    assert row["ok"], row


def _sleep(seconds: float) -> float:
    import time

    time.sleep(seconds)
    return seconds


@pytest.mark.slow
def test_a_cancel_does_not_wait_for_the_trees_in_flight():
    """The batch looks at Cancel while its trees run, not only when one ends."""
    from distributed import Client

    from amrst.campaign.batch import _as_they_end
    from amrst.errors import Cancelled

    class CancelSoon:
        calls = 0

        def check_cancelled(self) -> None:
            self.calls += 1
            if self.calls > 2:
                raise Cancelled()

    with Client(
        processes=False, n_workers=1, threads_per_worker=1, dashboard_address=":0"
    ) as client:  # any free port: another Dask on this machine may hold 8787
        future = client.submit(_sleep, 5.0)  # a tree that takes long
        with pytest.raises(Cancelled):
            next(_as_they_end([future], CancelSoon()))
        assert not future.done()  # Cancel came while the tree still ran
        future.cancel()


def test_a_tree_writes_nothing_over_another_runs_results(
    tmp_path, sample_pair, monkeypatch
):
    # Another run (a second batch on the campaign) writes the tree's results while
    # this one registers it: this run's are the ones not written, and it says so.
    import amrst.multiscan
    from amrst.campaign.run import run_tree

    tree = _one_tree(tmp_path, sample_pair)
    theirs = tmp_path / "results" / "T01" / "transform.json"
    register = amrst.multiscan.register_scans

    def meanwhile(*args, **kwargs):
        theirs.write_text('{"the other run": true}')
        return register(*args, **kwargs)

    monkeypatch.setattr(amrst.multiscan, "register_scans", meanwhile)
    row = run_tree(*tree)
    assert not row["ok"]
    assert "changed while this run worked (another run wrote it)" in row["error"]
    assert theirs.read_text() == '{"the other run": true}'
