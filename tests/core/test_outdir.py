"""An output folder is replaced as one unit, and two writers never interleave.

The kill tests fork a child that runs a real export and SIGKILLs itself at the k-th
file-system step (rename, exchange, unlink), for every k until the export finishes.
After each kill the folder must hold the complete old set or the complete new set
(swap mode: at once; journal mode: once the next run has recovered), and the next run
must leave no debris.
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest

from amrst.errors import AmrstError
from amrst.files import outdir
from amrst.files.folderlock import FolderBusy, FolderLock
from amrst.results.export import export_registration
from amrst.types import Cloud, make_transform

pytestmark = pytest.mark.skipif(
    not hasattr(os, "fork") or outdir._RENAMEAT2 is None, reason="POSIX with renameat2"
)


def _scans() -> tuple[Cloud, Cloud]:
    rng = np.random.default_rng(0)
    target = Cloud(rng.uniform(0, 5, (300, 3)), name="target.ply")
    source = Cloud(rng.uniform(0, 5, (200, 3)), name="source.ply")
    return target, source


def _export(out: Path, shift: float, fmt: str, **kw) -> None:
    target, source = _scans()
    export_registration(
        out,
        target=target,
        source=source,
        T_target_source=make_transform(np.eye(3), [shift, 0.0, 0.0]),
        metrics={"shift": shift},
        cloud_format=fmt,
        remove_stale=True,
        **kw,
    )


def _content(path: Path) -> object:
    """A file's content without the creation time (it differs between runs)."""
    if path.suffix == ".json":
        doc = json.loads(path.read_text(encoding="utf-8"))
        doc.pop("created", None)
        return doc
    return path.read_bytes()


def _visible(folder: Path) -> dict[str, object]:
    return {
        p.name: _content(p)
        for p in folder.iterdir()
        if not p.name.startswith(".") and p.name != "notes.txt"
    }


def _debris(folder: Path) -> list[str]:
    inside = [p.name for p in folder.iterdir() if p.name.startswith(".")]
    beside = [p.name for p in folder.parent.iterdir() if ".amrst-swap-" in p.name]
    return inside + beside


def _killed_at(k: int, out: Path) -> bool:
    """Export the new set in a forked child killed at its k-th file-system step."""
    pid = os.fork()
    if pid == 0:  # the child: count the steps, die at the k-th
        try:
            count = [0]

            def hook(real):
                def step(*args, **kwargs):
                    count[0] += 1
                    if count[0] == k:
                        os.kill(os.getpid(), signal.SIGKILL)
                    return real(*args, **kwargs)

                return step

            os.replace, os.rename, os.unlink = map(
                hook, (os.replace, os.rename, os.unlink)
            )
            outdir.exchange = hook(outdir.exchange)
            _export(out, 1.0, "ply")
        finally:
            os._exit(0)
    _, status = os.waitpid(pid, 0)
    return os.WIFSIGNALED(status)


@pytest.mark.parametrize("shared", [False, True], ids=["swap", "journal"])
def test_a_kill_at_every_step_leaves_the_old_or_the_new_set(
    tmp_path: Path, shared: bool
) -> None:
    old_ref, new_ref = tmp_path / "old", tmp_path / "new"
    _export(old_ref, 0.0, "pcd")
    _export(new_ref, 1.0, "ply")
    old, new = _visible(old_ref), _visible(new_ref)
    assert old != new
    assert set(old) != set(new)
    k, outcomes = 0, set()
    while True:
        k += 1
        out = tmp_path / f"run{k}" / "out"
        _export(out, 0.0, "pcd")
        if shared:  # a file that is not ours: the folder cannot be swapped whole
            (out / "notes.txt").write_text("mine")
        killed = _killed_at(k, out)
        now = _visible(out)
        if not shared:  # swap: whole at every instant, before any recovery
            assert now in (old, new), f"kill at step {k} left a mix: {sorted(now)}"
        with FolderLock(out, timeout_s=5):
            outdir.recover(out)
        now = _visible(out)
        assert now in (old, new), f"kill at step {k}: a mix after recovery"
        outcomes.add("new" if now == new else "old")
        assert _debris(out) == [], f"kill at step {k} left {_debris(out)}"
        if shared:
            assert (out / "notes.txt").read_text() == "mine"
        if not killed:
            break
        assert k < 200
    assert outcomes == {"old", "new"}
    assert k > 10  # every rename, exchange and unlink of the export was tried


def test_the_next_run_clears_debris_of_killed_runs(tmp_path: Path) -> None:
    out = tmp_path / "out"
    _export(out, 0.0, "ply")
    (out / ".amrst-export-abc123").mkdir()
    (out / ".amrst-export-abc123" / "merged.ply").write_bytes(b"x" * 1000)
    sibling = tmp_path / ".out.amrst-swap-xyz"
    sibling.mkdir()
    (sibling / "merged.ply").write_bytes(b"half")
    _export(out, 1.0, "ply")
    assert _debris(out) == []
    assert json.loads((out / "metrics.json").read_text())["shift"] == 1.0


def test_a_failed_write_leaves_the_old_set_and_no_debris(tmp_path: Path) -> None:
    out = tmp_path / "out"
    _export(out, 0.0, "ply")
    before = _visible(out)

    def boom(path: Path) -> None:
        path.write_bytes(b"half")
        raise OSError(28, "No space left on device")

    with pytest.raises(AmrstError, match="No space left") as exc:
        outdir.replace_files(out, {"transform.json": boom}, managed={"transform.json"})
    assert str(out) in str(exc.value)
    assert ".amrst" not in str(exc.value)
    assert _visible(out) == before
    assert _debris(out) == []


def test_a_folder_another_run_wrote_meanwhile_is_not_written(tmp_path: Path) -> None:
    out = tmp_path / "out"
    _export(out, 0.0, "ply")
    names = ["transform.json", "metrics.json", "report.html"]
    seen = outdir.folder_stamp(out, names)
    assert seen["transform.json"] is not None
    assert seen["report.html"] is None
    _export(out, 1.0, "ply")  # another run, while this one worked
    before = _visible(out)
    with pytest.raises(outdir.FolderChanged, match="another run wrote it"):
        outdir.replace_files(
            out,
            {"transform.json": lambda p: p.write_text("{}")},
            managed={"transform.json"},
            unchanged=seen,
        )
    assert _visible(out) == before
    assert _debris(out) == []
    # Unchanged since it was seen: written.
    seen = outdir.folder_stamp(out, names)
    outdir.replace_files(
        out,
        {"transform.json": lambda p: p.write_text("{}")},
        managed={"transform.json"},
        unchanged=seen,
    )
    assert (out / "transform.json").read_text() == "{}"


_WRITER = textwrap.dedent(
    """
    import os, sys, time
    sys.path.insert(0, {tests!r})
    from test_outdir import _export
    import amrst.files.outdir as od
    shift, slow_s, timeout_s = float(sys.argv[1]), float(sys.argv[2]), float(sys.argv[3])
    real = od._write_into
    def slow(*a, **k):
        print("writing", flush=True)
        time.sleep(slow_s)
        return real(*a, **k)
    od._write_into = slow
    print("ready", flush=True)
    sys.stdin.readline()  # imports done: wait for the test's go
    _export(sys.argv[4], shift, "ply", lock_timeout_s=timeout_s)
    print("done", flush=True)
    """
)


def _writer(tmp_path: Path, out: Path, shift: float, slow_s: float, timeout_s: float):
    # One script a writer: rewriting a shared one could empty it under a writer
    # still starting (it then printed nothing and the test failed on a busy machine).
    script = tmp_path / f"writer_{shift:g}.py"
    script.write_text(_WRITER.format(tests=str(Path(__file__).parent)))
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(sys.path)}
    return subprocess.Popen(
        [
            sys.executable,
            str(script),
            str(shift),
            str(slow_s),
            str(timeout_s),
            str(out),
        ],
        stdin=subprocess.PIPE,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        env=env,
    )


def test_two_processes_writing_one_folder_take_turns(tmp_path: Path) -> None:
    out = tmp_path / "out"
    first = _writer(tmp_path, out, 1.0, slow_s=1.5, timeout_s=60)
    second = _writer(tmp_path, out, 2.0, slow_s=0.0, timeout_s=60)
    busy = _writer(tmp_path, out, 3.0, slow_s=0.0, timeout_s=0)
    procs = (first, second, busy)
    for p in procs:
        assert p.stdout is not None
        assert p.stdout.readline().strip() == "ready"

    def go(p: subprocess.Popen) -> None:
        assert p.stdin is not None
        p.stdin.write("go\n")
        p.stdin.flush()

    go(first)
    assert first.stdout.readline().strip() == "writing"  # it holds the lock now
    go(second)
    go(busy)
    outs = [p.communicate(timeout=120) for p in procs]
    assert first.returncode == 0, outs
    assert second.returncode == 0, outs
    assert "Waiting for another AMRST run" in outs[1][1]
    # The impatient one gave up with the holder's name, and wrote nothing.
    assert busy.returncode != 0
    assert f"pid {first.pid} on " in outs[2][1]
    assert "FolderBusy" in outs[2][1]
    # The last writer's complete set, not a mix of both.
    metrics = json.loads((out / "metrics.json").read_text())
    assert metrics["shift"] == 2.0
    assert json.loads((out / "transform.json").read_text())["T_target_source"][0][
        3
    ] == pytest.approx(2.0)
    assert _debris(out) == []


def test_the_lock_of_a_dead_holder_is_taken_at_once(tmp_path: Path) -> None:
    proc = subprocess.run(
        [
            sys.executable,
            "-c",
            "import sys, os, signal; from amrst.files.folderlock import FolderLock; "
            "FolderLock(sys.argv[1]).acquire(); os.kill(os.getpid(), signal.SIGKILL)",
            str(tmp_path),
        ],
        env={**os.environ, "PYTHONPATH": os.pathsep.join(sys.path)},
        check=False,
    )
    assert proc.returncode == -signal.SIGKILL
    assert (tmp_path / ".amrst-lock").is_file()  # left behind, naming a dead pid
    with FolderLock(tmp_path, timeout_s=0):  # no wait: a held lock would raise
        pass
    assert not (tmp_path / ".amrst-lock").exists()


def test_a_held_lock_names_its_holder(tmp_path: Path) -> None:
    with FolderLock(tmp_path), pytest.raises(FolderBusy, match=f"pid {os.getpid()}"):
        FolderLock(tmp_path, timeout_s=0.2).acquire()


def test_files_in_a_new_subfolder_land_and_old_ones_go_in_journal_mode(tmp_path):
    # A file the set does not manage puts the folder in journal mode.
    (tmp_path / "notes.txt").write_text("mine")
    writers = {
        "a.txt": lambda p: p.write_text("a"),
        "sub/b.txt": lambda p: (p.parent.mkdir(exist_ok=True), p.write_text("b")),
    }
    outdir.replace_files(tmp_path, writers, managed={"a.txt", "sub"})
    assert (tmp_path / "sub" / "b.txt").read_text() == "b"
    (tmp_path / "sub" / "old.txt").write_text("old")
    outdir.replace_files(
        tmp_path,
        {"a.txt": lambda p: p.write_text("a2")},
        managed={"a.txt", "sub"},
        remove=["sub/old.txt", "sub/b.txt", "../notes.txt"],
    )
    assert not (tmp_path / "sub").exists()  # left empty: removed with its files
    assert (tmp_path / "notes.txt").read_text() == "mine"  # outside names are refused
    assert (tmp_path / "a.txt").read_text() == "a2"
    (tmp_path / "sub").mkdir()
    (tmp_path / "sub" / "b.txt").write_text("b")
    (tmp_path / "sub" / "yours.txt").write_text("yours")  # not the set's: it stays
    outdir.replace_files(
        tmp_path,
        {"a.txt": lambda p: p.write_text("a3")},
        managed={"a.txt", "sub"},
        remove=["sub/b.txt"],
    )
    assert sorted(p.name for p in (tmp_path / "sub").iterdir()) == ["yours.txt"]
