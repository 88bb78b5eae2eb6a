"""amrst batch on real Dask clusters: a LocalCluster of processes, a scheduler and
workers started as separate processes, a corrupt scan among good ones, kill and resume.
"""

from __future__ import annotations

import csv
import json
import os
import shutil
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import numpy as np
import pytest

from amrst.campaign import init_campaign, load_campaign, run_batch
from amrst.campaign.batch import DEFAULT_WORKERS

ROOT = Path(__file__).resolve().parents[2]
pytestmark = pytest.mark.slow


def _env() -> dict[str, str]:
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join([str(ROOT), env.get("PYTHONPATH", "")])
    return env


def _pair_tree(root: Path, tree_id: str, sample_pair) -> None:
    (root / tree_id).mkdir(parents=True)
    for name in ("target.ply", "source.ply", "truth.json"):
        shutil.copy(sample_pair.target_path.parent / name, root / tree_id / name)


def _corrupt_tree(root: Path, tree_id: str, sample_pair) -> None:
    (root / tree_id).mkdir(parents=True)
    shutil.copy(sample_pair.target_path, root / tree_id / "a.ply")
    data = sample_pair.source_path.read_bytes()
    (root / tree_id / "b.ply").write_bytes(data[: len(data) // 3])


def _transform(root: Path, tree_id: str) -> np.ndarray:
    doc = json.loads((root / "results" / tree_id / "transform.json").read_text())
    return np.asarray(doc["T_target_source"])


def _rows(root: Path) -> dict[str, dict[str, str]]:
    with open(root / "campaign.csv", newline="") as f:
        return {r["tree_id"]: r for r in csv.DictReader(f)}


def test_local_cluster_corrupt_scan_and_resume(
    tmp_path, sample_pair, sample_run, tiny_tree
):
    from amrst.multiscan.simulate import simulate_scans, write_scans

    _pair_tree(tmp_path, "T01", sample_pair)
    write_scans(simulate_scans(tiny_tree, 3, seed=0, res_deg=0.2), tmp_path / "T02")
    _corrupt_tree(tmp_path, "T03", sample_pair)
    campaign, _ = init_campaign(tmp_path)
    summary = run_batch(campaign, workers=DEFAULT_WORKERS, clouds="ply")
    assert sorted(summary.finished) == ["T01", "T02"]
    assert list(summary.errors) == ["T03"]
    assert "b.ply" in summary.errors["T03"]
    # the batch gives exactly what amrst.register gives alone
    assert np.array_equal(
        _transform(tmp_path, "T01"), sample_run.result.T_target_source
    )
    assert len({r["worker"] for r in summary.results}) >= 1
    rows = _rows(tmp_path)
    assert rows["T01"]["status"] == "registered"
    assert float(rows["T01"]["TH"]) > 10
    assert rows["T02"]["links_verified"] == "3"
    assert rows["T03"]["status"] == "failed"
    assert "b.ply" in rows["T03"]["error"]
    assert summary.statuses == {"T01": "registered", "T02": "registered"}
    assert summary.counts() == (
        "2 registered, 0 needs review, 1 failed (1 with an error), 0 already done"
    )
    for tree in ("T01", "T02"):  # each tree's report, the pair's or the many scans'
        page = (tmp_path / "results" / tree / "report.html").read_text()
        assert ">Registered<" in page
    for tree in ("T01", "T02"):  # truth read from the tree folder's truth.json
        scans = json.loads((tmp_path / "results" / tree / "scans.json").read_text())
        assert all(s["truth"]["registered"] for s in scans["scans"])
    from amrst import io

    merged = io.read(tmp_path / "results" / "T02" / "merged.ply")
    assert set(np.unique(merged.attributes["scan_id"])) == {0, 1, 2}
    # fix the corrupt scan: a re-run registers only that tree
    shutil.copy(sample_pair.source_path, tmp_path / "T03" / "b.ply")
    again = run_batch(load_campaign(tmp_path), workers=1, clouds="ply")
    assert sorted(again.skipped) == ["T01", "T02"]
    assert again.finished == ["T03"]
    assert _rows(tmp_path)["T03"]["status"] == "registered"
    # changed parameters invalidate every stamp
    from dataclasses import replace

    from amrst.campaign.batch import pending_trees
    from amrst.params import RegistrationParams

    base = RegistrationParams()
    changed = replace(base, fine=replace(base.fine, voxel_size_m=0.02))
    assert pending_trees(load_campaign(tmp_path), base, clouds="ply")[1] == [
        "T01",
        "T02",
        "T03",
    ]
    assert pending_trees(load_campaign(tmp_path), base)[1] == []  # no clouds: redo
    todo, done, _ = pending_trees(load_campaign(tmp_path), changed)
    assert done == []
    assert len(todo) == 3


def _start(args: list[str], log: Path) -> subprocess.Popen:
    with open(log, "w") as out:  # the child keeps its own copy of the descriptor
        return subprocess.Popen(
            [sys.executable, *args],
            env=_env(),
            stdout=out,
            stderr=subprocess.STDOUT,
            start_new_session=True,
        )


def _stop(procs: list[subprocess.Popen]) -> None:
    for p in procs:
        if p.poll() is None:
            os.killpg(p.pid, signal.SIGTERM)
    for p in procs:
        try:
            p.wait(timeout=10)
        except subprocess.TimeoutExpired:
            os.killpg(p.pid, signal.SIGKILL)
            p.wait(timeout=10)


def test_separately_started_scheduler_and_workers(tmp_path, sample_pair, sample_run):
    from distributed import Client

    _pair_tree(tmp_path / "camp", "T01", sample_pair)
    _corrupt_tree(tmp_path / "camp", "T02", sample_pair)
    campaign, _ = init_campaign(tmp_path / "camp")
    file = tmp_path / "scheduler.json"
    procs = [
        _start(
            [
                "-m",
                "distributed.cli.dask_scheduler",
                "--host",
                "127.0.0.1",
                "--port",
                "0",
                "--no-dashboard",
                "--scheduler-file",
                str(file),
            ],
            tmp_path / "scheduler.log",
        )
    ]
    try:
        deadline = time.monotonic() + 30
        while not file.is_file() and time.monotonic() < deadline:
            time.sleep(0.1)
        assert file.is_file(), (tmp_path / "scheduler.log").read_text()
        for k in range(2):
            procs.append(
                _start(
                    [
                        "-m",
                        "distributed.cli.dask_worker",
                        "--scheduler-file",
                        str(file),
                        "--nthreads",
                        "1",
                        "--no-dashboard",
                        "--name",
                        f"w{k}",
                    ],
                    tmp_path / f"worker{k}.log",
                )
            )
        address = json.loads(file.read_text())["address"]
        assert address.startswith("tcp://127.0.0.1:")
        with Client(address, timeout="20s") as client:
            client.wait_for_workers(2, timeout=30)
        summary = run_batch(campaign, scheduler=address)
        assert summary.workers == 2
        assert summary.finished == ["T01"]
        assert list(summary.errors) == ["T02"]
        assert np.array_equal(
            _transform(tmp_path / "camp", "T01"), sample_run.result.T_target_source
        )
    finally:
        _stop(procs)
    assert all(p.poll() is not None for p in procs)


def test_sigkill_then_resume_loses_only_trees_in_flight(
    tmp_path, sample_pair, sample_run
):
    for k in range(4):
        _pair_tree(tmp_path, f"T{k}", sample_pair)
    init_campaign(tmp_path)
    batch = _start(
        ["-m", "amrst.cli", "batch", str(tmp_path), "--workers", "1", "--quiet"],
        tmp_path / "batch.log",
    )
    stamps = [tmp_path / "results" / f"T{k}" / "stamp.json" for k in range(4)]
    try:
        deadline = time.monotonic() + 60
        while not any(s.is_file() for s in stamps) and time.monotonic() < deadline:
            time.sleep(0.05)
    finally:
        os.killpg(batch.pid, signal.SIGKILL)  # the batch and its workers, at once
        batch.wait(timeout=10)
    done_before = {s.parent.name for s in stamps if s.is_file()}
    assert done_before, (tmp_path / "batch.log").read_text()
    assert len(done_before) < 4, "the batch finished before it was killed"
    summary = run_batch(load_campaign(tmp_path), workers=1)
    assert set(summary.skipped) == done_before
    assert set(summary.finished) == {f"T{k}" for k in range(4)} - done_before
    for k in range(4):
        assert np.array_equal(
            _transform(tmp_path, f"T{k}"), sample_run.result.T_target_source
        )
    assert {r["status"] for r in _rows(tmp_path).values()} == {"registered"}


def test_a_scheduler_that_cannot_be_reached_is_one_line():
    from amrst.campaign.batch import _client
    from amrst.errors import InvalidInput

    with pytest.raises(InvalidInput, match="tcp://HOST:PORT") as info:
        _client(1, "garbage")
    assert "\n" not in str(info.value)


def test_a_results_file_in_the_way_is_refused_before_any_tree(tmp_path, sample_pair):
    from amrst.errors import InvalidInput

    _pair_tree(tmp_path, "T01", sample_pair)
    init_campaign(tmp_path)
    (tmp_path / "results").write_text("not a folder")
    with pytest.raises(InvalidInput, match="results folder"):
        run_batch(load_campaign(tmp_path), workers=1)


_ONE_TREE = textwrap.dedent(
    """
    import json, sys
    from pathlib import Path
    from amrst.campaign import load_campaign
    from amrst.campaign.run import run_tree, tree_stamp
    from amrst.params import RegistrationParams, params_to_dict

    root = sys.argv[1]
    (entry,) = load_campaign(root).trees
    doc = params_to_dict(RegistrationParams())
    stamp = tree_stamp(Path(root), entry, doc)
    print(json.dumps(run_tree(root, entry, doc, stamp)))
    """
)


def test_a_tree_whose_scans_are_one_scan_twice_fails_as_register_refuses(
    tmp_path, sample_pair
):
    (tmp_path / "T01").mkdir()
    for name in ("target.ply", "source.ply"):  # a copy of the same scan
        shutil.copy(sample_pair.target_path, tmp_path / "T01" / name)
    init_campaign(tmp_path)
    # The tree runs in a process of its own, as on a Dask worker: run in the test
    # process it kept Dask from starting the clusters of later tests.
    out = subprocess.run(
        [sys.executable, "-c", _ONE_TREE, str(tmp_path)],
        env=_env(),
        capture_output=True,
        text=True,
        check=True,
    )
    got = json.loads(out.stdout.strip().splitlines()[-1])
    assert not got["ok"]
    assert "holds the same points as" in got["error"]
