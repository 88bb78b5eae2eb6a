"""How amrst batch spreads trees over workers: longest first, one core per
task, the workers' imports before the first tree; the result never depends on it.
"""

from __future__ import annotations

import json
import os
import shutil
import threading
from typing import TYPE_CHECKING

import numpy as np
import pytest

from amrst.campaign import Campaign, TreeEntry, init_campaign, run_batch
from amrst.campaign.plan import longest_first, scan_threads, time_left, tree_cost

if TYPE_CHECKING:
    from pathlib import Path


def _tree(root: Path, tree_id: str, sizes: dict[str, int]) -> TreeEntry:
    (root / tree_id).mkdir(parents=True)
    for name, size in sizes.items():
        (root / tree_id / name).write_bytes(b"x" * size)
    return TreeEntry(id=tree_id, scans=tuple(f"{tree_id}/{n}" for n in sizes))


def _five(root: Path) -> list[TreeEntry]:
    return [
        TreeEntry(id="gone", scans=("gone/a.ply", "gone/b.ply")),
        _tree(root, "small", {"a.ply": 10, "b.ply": 10}),
        _tree(root, "big", {"a.ply": 500, "b.ply": 10}),
        _tree(root, "tie", {"a.ply": 15, "b.ply": 5}),
        _tree(root, "four", {f"s{k}.ply": 100 for k in range(4)}),
    ]


def test_first_run_goes_by_bytes_ties_in_manifest_order(tmp_path) -> None:
    trees = _five(tmp_path)
    assert tree_cost(tmp_path, trees[4]) == 400
    assert tree_cost(tmp_path, trees[0]) == 0  # reported when the tree runs
    ordered, costs = longest_first(
        Campaign(tmp_path, tuple(trees)), [(e, e.id) for e in trees]
    )
    assert costs == {"gone": 0, "small": 20, "big": 510, "tie": 20, "four": 400}
    assert [s for _, s in ordered] == ["big", "four", "small", "tie", "gone"]


def test_a_tree_run_before_costs_the_seconds_it_took(tmp_path) -> None:
    from amrst.campaign.run import ERROR, STAMP

    trees = _five(tmp_path)
    campaign = Campaign(tmp_path, tuple(trees))
    for tree_id, name, seconds in (("small", STAMP, 8.0), ("big", ERROR, 0.5)):
        campaign.results_dir(tree_id).mkdir(parents=True)
        (campaign.results_dir(tree_id) / name).write_text(
            json.dumps({"seconds": seconds})
        )
    ordered, costs = longest_first(campaign, [(e, e.id) for e in trees])
    # seconds per byte: small 8/20, big 0.5/510; the median of two is the larger
    assert costs["small"] == 8.0
    assert costs["big"] == 0.5
    assert costs["four"] == pytest.approx(400 * 8 / 20)
    assert costs["tie"] == pytest.approx(8.0)  # ties with small: manifest order
    assert [s for _, s in ordered] == ["four", "small", "tie", "big", "gone"]


def test_time_left_follows_the_bytes_done() -> None:
    # the biggest tree (half the bytes) took 10 s: about 10 s left, not 10 x 3
    assert time_left(10.0, 1, 4, 500, 1000) == pytest.approx(10.0)
    assert time_left(10.0, 2, 4, 0, 0) == pytest.approx(10.0)  # no size known: count
    assert time_left(10.0, 4, 4, 1000, 1000) == 0.0


@pytest.mark.parametrize(
    ("cores", "tasks", "threads"),
    [(2, 1, 2), (2, 2, 1), (1, 1, 1), (3, 2, 1), (4, 2, 2), (16, 2, 2), (8, 8, 1)],
)
def test_a_task_gets_two_threads_only_with_two_cores_of_its_own(
    cores: int, tasks: int, threads: int
) -> None:
    assert scan_threads(cores, tasks) == threads


def test_the_pair_s_scans_run_in_the_calling_thread() -> None:
    from amrst.pipeline import both_scans

    def where(item: str, _rep: object) -> tuple[str, str]:
        return item, threading.current_thread().name

    here = threading.current_thread().name
    assert both_scans(where, "t", "s") == (("t", here), ("s", here))


def test_one_or_two_scan_threads_give_the_same_result(tmp_path, sample_pair) -> None:
    from amrst.campaign.batch import pending_trees
    from amrst.campaign.run import run_tree

    (tmp_path / "T01").mkdir()
    for name in ("target.ply", "source.ply"):
        shutil.copy(sample_pair.target_path.parent / name, tmp_path / "T01" / name)
    campaign, _ = init_campaign(tmp_path)
    (entry, stamp), *_ = pending_trees(campaign)[0]
    poses = []
    for threads in (1, 2):
        assert run_tree(
            str(tmp_path), entry, pending_trees(campaign)[2], stamp, "", threads
        )["ok"]
        doc = json.loads((tmp_path / "results" / "T01" / "transform.json").read_text())
        poses.append(doc["T_target_source"])
    assert poses[0] == poses[1]


WARM_CHECK = r"""
import json, sys
from amrst.campaign import load_campaign
from amrst.campaign.batch import pending_trees
from amrst.campaign.run import run_tree, warm_worker

campaign = load_campaign(sys.argv[1])
(entry, stamp), *_ = pending_trees(campaign)[0]
doc = pending_trees(campaign)[2]
warm_worker()
before = set(sys.modules)
row = run_tree(sys.argv[1], entry, doc, stamp, "", 1)
print(json.dumps({"ok": row["ok"], "new": sorted(set(sys.modules) - before)}))
"""


@pytest.mark.slow
def test_after_warm_worker_a_tree_imports_nothing_heavy(
    tmp_path, tiny_tree, json_script
) -> None:
    from amrst.multiscan.simulate import simulate_scans, write_scans

    write_scans(simulate_scans(tiny_tree, 2, seed=0, res_deg=0.2), tmp_path / "T01")
    init_campaign(tmp_path)
    doc = json_script(WARM_CHECK, str(tmp_path))
    assert doc["ok"]
    heavy = ("amrst", "scipy", "small_gicp", "kiss_matcher", "numpy", "threadpoolctl")
    late = [m for m in doc["new"] if m.split(".")[0] in heavy]
    assert late == [], f"add {late} to amrst.campaign.run.WARM_MODULES"


@pytest.mark.slow
def test_one_worker_runs_the_biggest_tree_first(tmp_path, sample_pair, tiny_tree):
    """Manifest order is smallest first; a LocalCluster worker takes them biggest first."""
    from amrst.multiscan.simulate import simulate_scans, write_scans

    write_scans(simulate_scans(tiny_tree, 2, seed=0, res_deg=0.4), tmp_path / "A-small")
    write_scans(simulate_scans(tiny_tree, 2, seed=1, res_deg=0.2), tmp_path / "B-mid")
    (tmp_path / "C-big").mkdir()
    for name in ("target.ply", "source.ply"):
        shutil.copy(sample_pair.target_path.parent / name, tmp_path / "C-big" / name)
    campaign, _ = init_campaign(tmp_path)
    costs = {t.id: tree_cost(tmp_path, t) for t in campaign.trees}
    assert costs["A-small"] < costs["B-mid"] < costs["C-big"], costs
    summary = run_batch(campaign, workers=1)
    assert [r["id"] for r in summary.results] == ["C-big", "B-mid", "A-small"]
    assert np.all([r["ok"] for r in summary.results])


def test_threads_per_tree_reaches_every_tree(tmp_path, tiny_tree) -> None:
    """--threads-per-tree pins the threads a tree uses; out of range is one line."""
    import json

    from amrst.errors import InvalidInput
    from amrst.multiscan.simulate import simulate_scans, write_scans

    for k in range(2):
        write_scans(
            simulate_scans(tiny_tree, 2, seed=k, res_deg=0.4), tmp_path / f"T{k}"
        )
    campaign, _ = init_campaign(tmp_path)
    with pytest.raises(InvalidInput, match="--threads-per-tree must be 1 or 2"):
        run_batch(campaign, workers=1, threads_per_tree=3)
    # More local workers than cores would only share them: refused before any starts.
    with pytest.raises(InvalidInput, match=r"--workers must be 1 to \d+ \(this"):
        run_batch(campaign, workers=1000)
    summary = run_batch(campaign, workers=1, threads_per_tree=1)
    assert sorted(summary.finished) == ["T0", "T1"]
    for tree in ("T0", "T1"):
        stamp = json.loads((tmp_path / "results" / tree / "stamp.json").read_text())
        assert stamp["threads"] == 1
    with pytest.raises(InvalidInput, match="--workers must be 1 to"):  # all done: still
        run_batch(campaign, workers=0)


def _worker_env() -> dict[str, object]:
    import dask

    env: dict[str, object] = {
        k: os.environ.get(k) for k in ("MALLOC_TRIM_THRESHOLD_", "OMP_NUM_THREADS")
    }
    env["profile"] = dask.config.get("distributed.worker.profile.enabled")
    return env


@pytest.mark.slow
def test_local_workers_keep_glibc_memory_trimming_as_amrst_register() -> None:
    """Dask's 65536-byte trim threshold costs CPU on every tree (freed memory is
    handed back and faulted in again), and so does its profiler, which samples every
    task's stack: a local cluster turns both off."""
    from amrst.campaign.batch import _client

    if "MALLOC_TRIM_THRESHOLD_" in os.environ:
        pytest.skip("set in this environment: the workers inherit it")
    client, cluster = _client(1, None)
    try:
        (env,) = client.run(_worker_env).values()
    finally:
        client.close()
        cluster.close()
    assert env == {
        "MALLOC_TRIM_THRESHOLD_": None,
        "OMP_NUM_THREADS": "1",
        "profile": False,
    }
