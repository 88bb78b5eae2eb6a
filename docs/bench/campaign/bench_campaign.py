"""Benchmarks of issue 14 (campaigns, multi-scan trees, batch on Dask).

Run from the repository root (needs ../shared/data)::

    python docs/bench/campaign/bench_campaign.py build      # campaign folder + amrst register alone
    python docs/bench/campaign/bench_campaign.py workers    # --workers 1 then 2, same run
    AMRST_BENCH_OLD=/path/to/old/checkout ... workers          # and the old code, same run
    AMRST_BENCH_THREADS=1 AMRST_BENCH_KEY=workers_1thread ... workers  # one thread a tree
    python docs/bench/campaign/bench_campaign.py external   # scheduler + 2 workers as processes
    python docs/bench/campaign/bench_campaign.py kill       # SIGKILL at 3 random moments, resume
    python docs/bench/campaign/bench_campaign.py fourscan   # 4-scan trees from 10 shared trees

Each step appends its figures to docs/bench/campaign/results.json.
"""

from __future__ import annotations

import json
import os
import random
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[3]
DATA = REPO.parent / "shared" / "data"
if not DATA.is_dir():
    DATA = Path("/work/shared/data")
WORK = Path(os.environ.get("AMRST_BENCH_DIR", "/tmp/amrst-campaign-bench"))
CAMP = WORK / "campaign"
ALONE = WORK / "alone"
OUT = Path(__file__).resolve().parent / "results.json"
PY = sys.executable
ENV = {**os.environ, "PYTHONPATH": str(REPO)}
FOUR_TREES = [
    "itsme/tree_1_pc.txt",
    "itsme/tree_2_pc.txt",
    "itsme/buttressed_tree_1_pc.txt",
    "itsme/buttressed_tree_2_pc.txt",
    "archi/Tree_1_point_cloud.las",
    "archi/Tree_2_point_cloud.las",
    "voxr/Tree_t0.asc",
    "rtls/pc_tree.txt",
    "treels/pine.laz",
    "pytlidar/tree_1.las",
]


def record(key: str, value: object) -> None:
    doc = json.loads(OUT.read_text()) if OUT.is_file() else {}
    doc[key] = value
    OUT.write_text(json.dumps(doc, indent=2) + "\n")
    print(json.dumps({key: value}, indent=2))


def amrst(*args: str, check: bool = True) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [PY, "-m", "amrst.cli", *args],
        env=ENV,
        capture_output=True,
        text=True,
        check=check,
    )


def transforms(results: Path) -> dict[str, list[list[float]]]:
    out = {}
    for folder in sorted(results.iterdir()):
        doc = (
            json.loads((folder / "transform.json").read_text())
            if (folder / "transform.json").is_file()
            else None
        )
        if doc is None:
            continue
        if "T_target_source" in doc:
            out[folder.name] = doc["T_target_source"]
        else:
            out[folder.name] = [s["T_reference_scan"] for s in doc["scans"]]
    return out


def build() -> None:
    shutil.rmtree(WORK, ignore_errors=True)
    CAMP.mkdir(parents=True)
    for group in ("cases", "cases_field"):
        for case in sorted(p for p in (DATA / group).iterdir() if p.is_dir()):
            dest = CAMP / f"{group}-{case.name}"
            dest.mkdir()
            for name in ("target.ply", "source.ply", "truth.json"):
                os.symlink(case / name, dest / name)
    amrst(
        "campaign",
        "simulate",
        str(DATA / "trees/itsme/tree_2_pc.txt"),
        "--out",
        str(CAMP / "sim4-itsme-tree2"),
        "--scans",
        "4",
        "--seed",
        "3",
    )
    init = amrst("campaign", "init", str(CAMP))
    print(init.stdout)
    # amrst register alone, one process per tree, as a user would run it
    t0 = time.perf_counter()
    for tree in sorted(p for p in CAMP.iterdir() if p.is_dir() and p.name != "results"):
        files = sorted(tree.glob("*.ply"))
        if (tree / "target.ply").exists():
            args = [str(tree / "target.ply"), str(tree / "source.ply")]
        else:
            args = [str(f) for f in files]
        amrst(
            "register", *args, "--out", str(ALONE / tree.name), "--quiet", check=False
        )
    record(
        "register_alone",
        {
            "trees": len(list(ALONE.iterdir())),
            "seconds": round(time.perf_counter() - t0, 1),
        },
    )


def _child(arg: str) -> None:
    """One batch in this process (PYTHONPATH picks the code); prints its figures."""
    job = json.loads(arg)
    from amrst.campaign import load_campaign, run_batch

    load = os.getloadavg()[0]
    pinned = (
        int(os.environ.get("AMRST_BENCH_THREADS", "0")) or None
    )  # --threads-per-tree
    s = run_batch(
        load_campaign(CAMP),
        workers=job["workers"],
        scheduler=job["scheduler"],
        force=job["force"],
        threads_per_tree=pinned,
    )
    cpu = sum(r.get("cpu_seconds", 0.0) for r in s.results)
    busy: dict[str, float] = {}
    for r in s.results:
        busy[r["worker"]] = busy.get(r["worker"], 0.0) + r.get("seconds", 0.0)
    n = len(s.registered) + len(s.failed)
    print(
        json.dumps(
            {
                "code": job["code"],
                "registered": len(s.registered),
                "failed": s.failed,
                "skipped": len(s.skipped),
                "seconds_total": round(s.seconds, 1),
                "seconds_running": round(s.run_seconds, 1),
                "trees_per_hour": round(s.trees_per_hour),
                # the whole call: cluster start (and, new code, the workers' imports) included
                "trees_per_hour_whole_call": round(3600 * n / s.seconds)
                if s.seconds
                else 0,
                "workers": s.workers,
                # CPU time of the workers (every thread) over the wall time: the cores the
                # batch got; with other jobs on the machine it cannot reach the worker count.
                "cpu_seconds": round(cpu, 1),
                "cores_used": round(cpu / s.run_seconds, 2) if s.run_seconds else 0.0,
                # wall time the workers spent between trees or after their last one
                "idle_worker_seconds": round(
                    s.workers * s.run_seconds - sum(busy.values()), 1
                ),
                "load_average_1min_before": round(load, 2),
            }
        )
    )


def _batch(
    workers: int,
    scheduler: str | None = None,
    force: bool = True,
    repo: Path = REPO,
    code: str = "new",
) -> dict[str, object]:
    """Run one batch in a fresh process on the code at ``repo``."""
    job = json.dumps(
        {"workers": workers, "scheduler": scheduler, "force": force, "code": code}
    )
    out = subprocess.run(
        [PY, str(Path(__file__).resolve()), "_child", job],
        env={**os.environ, "PYTHONPATH": str(repo)},
        capture_output=True,
        text=True,
        check=True,
    )
    return json.loads(out.stdout.strip().splitlines()[-1])  # type: ignore[no-any-return]


def workers() -> None:
    """--workers 1 and 2, alternated (1, 2, 1, 2) so both see the same load.

    With AMRST_BENCH_OLD=<a checkout of older code> the old code runs in the same run
    too, interleaved (new 1, new 2, old 1, old 2, then old 2, old 1, new 2, new 1), for
    the before/after figures.
    """
    load = os.getloadavg()
    old = os.environ.get("AMRST_BENCH_OLD")
    sim = (
        CAMP / "sim4-itsme-tree2"
    )  # amrst register alone again for the multi-scan tree
    amrst(
        "register",
        *[str(f) for f in sorted(sim.glob("*.ply"))],
        "--out",
        str(ALONE / sim.name),
        "--quiet",
        check=False,
    )
    plan = [("new", 1), ("new", 2), ("new", 1), ("new", 2)]
    if old:
        plan = [
            ("new", 1),
            ("new", 2),
            ("old", 1),
            ("old", 2),
            ("old", 2),
            ("old", 1),
            ("new", 2),
            ("new", 1),
        ]
    runs = []
    ref: dict[str, dict[str, object]] = {}
    same = {"new": True, "old": True}
    for code, n in plan:
        runs.append(_batch(n, repo=Path(old) if code == "old" else REPO, code=code))
        now = transforms(CAMP / "results")
        same[code] = same[code] and (code not in ref or now == ref[code])
        ref.setdefault(code, now)  # type: ignore[arg-type]
        print(runs[-1], flush=True)
    alone = transforms(ALONE)
    equal_alone = {k: alone.get(k) == v for k, v in ref["new"].items()}

    def rate(code: str, n: int, key: str = "seconds_running") -> float:
        mine = [r for r, (c, k) in zip(runs, plan, strict=True) if (c, k) == (code, n)]
        return 3600 * sum(r["registered"] for r in mine) / sum(r[key] for r in mine)  # type: ignore[misc]

    doc: dict[str, object] = {
        "runs_in_order": runs,
        "trees_per_hour_1": round(rate("new", 1)),
        "trees_per_hour_2": round(rate("new", 2)),
        "speedup_trees_per_hour": round(rate("new", 2) / rate("new", 1), 2),
        "speedup_whole_call": round(
            rate("new", 2, "seconds_total") / rate("new", 1, "seconds_total"), 2
        ),
        "all_runs_identical": same["new"],
        "trees_equal_register_alone": sum(equal_alone.values()),
        "trees_compared": len(equal_alone),
        "differ": [k for k, v in equal_alone.items() if not v],
        "load_average_before": load,
    }
    if old:
        doc["old_code"] = old
        doc["old_trees_per_hour_1"] = round(rate("old", 1))
        doc["old_trees_per_hour_2"] = round(rate("old", 2))
        doc["old_speedup_trees_per_hour"] = round(rate("old", 2) / rate("old", 1), 2)
        doc["new_over_old_2_workers"] = round(rate("new", 2) / rate("old", 2), 2)
        doc["new_over_old_1_worker"] = round(rate("new", 1) / rate("old", 1), 2)
        doc["old_runs_identical"] = same["old"]
        doc["old_equal_new"] = sum(
            ref["old"].get(k) == v for k, v in ref["new"].items()
        )
    record(os.environ.get("AMRST_BENCH_KEY", "workers"), doc)


def external() -> None:
    ref = transforms(CAMP / "results")
    file = WORK / "scheduler.json"
    file.unlink(missing_ok=True)
    logs = [open(WORK / f"ext{i}.log", "w") for i in range(3)]  # noqa: SIM115 - closed below
    procs = [
        subprocess.Popen(
            [
                PY,
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
            env=ENV,
            stdout=logs[0],
            stderr=subprocess.STDOUT,
            start_new_session=True,
        )
    ]
    try:
        while not file.is_file():
            time.sleep(0.1)
        for k in range(2):
            procs.append(
                subprocess.Popen(
                    [
                        PY,
                        "-m",
                        "distributed.cli.dask_worker",
                        "--scheduler-file",
                        str(file),
                        "--nthreads",
                        "1",
                        "--no-dashboard",
                    ],
                    env=ENV,
                    stdout=logs[k + 1],
                    stderr=subprocess.STDOUT,
                    start_new_session=True,
                )
            )
        address = json.loads(file.read_text())["address"]
        from distributed import Client

        with Client(address) as c:
            c.wait_for_workers(2, timeout=60)
        run = _batch(2, scheduler=address)
    finally:
        for p in procs:
            os.killpg(p.pid, signal.SIGTERM)
        for p in procs:
            p.wait(timeout=30)
        for f in logs:
            f.close()
    record(
        "external_cluster",
        {
            **run,
            "address": address,
            "same_as_local": transforms(CAMP / "results") == ref,
        },
    )


def kill() -> None:
    ref = transforms(CAMP / "results")
    shutil.rmtree(CAMP / "results")
    rng = random.Random(14)
    rounds = []
    for _ in range(3):
        before = (
            {p.parent.name for p in (CAMP / "results").glob("*/stamp.json")}
            if (CAMP / "results").is_dir()
            else set()
        )
        log = open(WORK / "kill.log", "a")  # noqa: SIM115 - closed below
        p = subprocess.Popen(
            [PY, "-m", "amrst.cli", "batch", str(CAMP), "--workers", "2", "--quiet"],
            env=ENV,
            stdout=log,
            stderr=subprocess.STDOUT,
        )
        wait = rng.uniform(8.0, 30.0)
        time.sleep(wait)
        os.kill(p.pid, signal.SIGKILL)  # the batch process alone, as kill -9 PID does
        p.wait()
        log.close()
        time.sleep(3.0)
        orphans = subprocess.run(
            ["pgrep", "-f", "distributed"], capture_output=True, text=True
        ).stdout.split()
        after = {q.parent.name for q in (CAMP / "results").glob("*/stamp.json")}
        rounds.append(
            {
                "killed_after_s": round(wait, 1),
                "stamped_before": len(before),
                "stamped_after": len(after),
                "lost_stamps": len(before - after),
                "orphan_processes_3s_later": len(orphans),
            }
        )
    time.sleep(5.0)
    stamped = {q.parent.name for q in (CAMP / "results").glob("*/stamp.json")}
    final = _batch(2, force=False)
    record(
        "kill_resume",
        {
            "rounds": rounds,
            "stamped_before_final_run": len(stamped),
            "final_run": final,
            "final_registered_equals_unstamped": final["registered"]
            + len(final["failed"])
            == 31 - len(stamped),  # type: ignore[operator]
            "identical_to_uninterrupted": transforms(CAMP / "results") == ref,
        },
    )


def fourscan() -> None:
    sys.path.insert(0, str(REPO))
    from amrst import io
    from amrst.multiscan import register_scans
    from amrst.multiscan.simulate import simulate_scans
    from amrst.stages.metrics import truth_errors

    rows = []
    for k, rel in enumerate(FOUR_TREES):
        tree = io.read(DATA / "trees" / rel)
        if len(tree) > 150_000:
            tree = tree.select(
                np.random.default_rng(0).choice(len(tree), 150_000, replace=False)
            )
        sim = simulate_scans(tree, 4, seed=100 + k)
        seps = [
            round((b["azimuth_deg"] - a["azimuth_deg"]) % 360)
            for a, b in zip(sim.specs, sim.specs[1:], strict=False)
        ]
        t0 = time.perf_counter()
        res = register_scans(sim.scans, 0)
        secs = time.perf_counter() - t0
        truth = sim.T_reference_scan(0)
        per = []
        for s in range(1, 4):
            pts = sim.scans[s].xyz
            T, T_tree = res.T_reference_scan[s], res.T_tree[s]
            if T is None:
                per.append({"reached": False})
                continue
            e = truth_errors(T, truth[s], pts)
            et = truth_errors(T_tree, truth[s], pts)  # type: ignore[arg-type]
            per.append(
                {
                    "rot_deg": round(e.rotation_error_deg, 4),
                    "trans_cm": round(100 * e.translation_error_m, 2),
                    "gt_rmse_cm": round(100 * e.gt_rmse_m, 3),
                    "pairwise_gt_rmse_cm": round(100 * et.gt_rmse_m, 3),
                    "path": res.paths[s],
                }
            )
        ok = all(
            p.get("reached", True) and p["rot_deg"] < 1 and p["trans_cm"] < 5
            for p in per
        )

        # worst link: the relative transform of every pair of scans vs the truth
        def worst(poses, truth=truth, sim=sim):
            out = 0.0
            for a in range(4):
                for b in range(a + 1, 4):
                    if poses[a] is None or poses[b] is None:
                        return float("inf")
                    est = np.linalg.inv(poses[a]) @ poses[b]
                    tru = np.linalg.inv(truth[a]) @ truth[b]
                    out = max(out, truth_errors(est, tru, sim.scans[b].xyz).gt_rmse_m)
            return 100 * out

        rows.append(
            {
                "tree": rel,
                "separations_deg": seps,
                "ok": ok,
                "scans": per,
                "links_verified": sum(link.verified for link in res.links),
                "worst_link_gt_rmse_cm_joint": round(worst(res.T_reference_scan), 3),
                "worst_link_gt_rmse_cm_pairwise": round(worst(res.T_tree), 3),
                "joint_kept": None if res.joint is None else res.joint.kept,
                "seconds": round(secs, 1),
            }
        )
        print(rows[-1])
    record(
        "four_scan",
        {
            "trees_ok": sum(r["ok"] for r in rows),
            "trees": len(rows),
            "joint_no_worse_than_pairwise": sum(
                r["worst_link_gt_rmse_cm_joint"]
                <= r["worst_link_gt_rmse_cm_pairwise"] + 1e-9
                for r in rows
            ),
            "rows": rows,
        },
    )


if __name__ == "__main__":
    if sys.argv[1:2] == ["_child"]:
        _child(sys.argv[2])
        sys.exit(0)
    steps = {
        "build": build,
        "workers": workers,
        "external": external,
        "kill": kill,
        "fourscan": fourscan,
    }
    for name in sys.argv[1:] or list(steps):
        steps[name]()
