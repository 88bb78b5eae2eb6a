"""Hostile path arguments and values: one line, exit 2, never a hang.

None may hang, say "Internal error", print a traceback or raw numpy warnings, or exit
0 on bad input. FIFOs and devices run in a subprocess with a timeout, so a regression
fails instead of hanging the suite. Permission cases run in a forked child that drops
to the "nobody" user when the suite runs as root (root may enter any folder).
"""

from __future__ import annotations

import json
import os
import socket
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

# The forked unprivileged child cannot import from root's Python: import up front
# everything main() imports lazily.
import amrst.bench
import amrst.io.truth
import amrst.pipeline
import amrst.results.documents
import amrst.results.export
import amrst.simulate  # noqa: F401
from amrst.cli import main
from amrst.errors import InvalidInput
from amrst.params import params_from_dict
from amrst.types import Cloud

ENV = {**os.environ, "PYTHONPATH": os.pathsep.join(sys.path)}
DEEP = "[" * 100_000 + "]" * 100_000


def _one_line(err: str) -> str:
    lines = [line for line in err.splitlines() if line.strip()]
    assert len(lines) == 1, f"expected one line on stderr, got:\n{err[:2000]}"
    assert "Internal error" not in err
    assert "Traceback" not in err
    assert "Warning" not in err
    return lines[0]


def _register(sample_pair, tmp_path: Path, *extra: str) -> list[str]:
    return [
        "register",
        str(sample_pair.target_path),
        str(sample_pair.source_path),
        "--out",
        str(tmp_path / "out"),
        "--quiet",
        *extra,
    ]


def _subprocess(args: list[str]) -> tuple[int, str]:
    proc = subprocess.run(
        [sys.executable, "-m", "amrst.cli", *args],
        capture_output=True,
        text=True,
        timeout=60,
        env=ENV,
        check=False,
    )
    return proc.returncode, proc.stderr


@pytest.fixture
def fifo(tmp_path: Path) -> Path:
    path = tmp_path / "truth.json"
    os.mkfifo(path)
    return path


@pytest.mark.parametrize("option", ["--truth", "--params"])
def test_a_fifo_is_refused_at_once(sample_pair, tmp_path, fifo, option) -> None:
    code, err = _subprocess(_register(sample_pair, tmp_path, option, str(fifo)))
    assert code == 2
    assert "named pipe (FIFO)" in _one_line(err)


@pytest.mark.parametrize(
    ("option", "device"), [("--truth", "/dev/zero"), ("--params", "/dev/urandom")]
)
def test_a_device_is_refused_at_once(sample_pair, tmp_path, option, device) -> None:
    if not Path(device).exists():
        pytest.skip(f"no {device}")
    code, err = _subprocess(_register(sample_pair, tmp_path, option, device))
    assert code == 2
    assert "character device" in _one_line(err)


def _bad_file(tmp_path: Path, kind: str) -> Path:
    path = tmp_path / f"{kind}.json"
    if kind == "loop":
        path.symlink_to(path.name)
    elif kind == "deep":
        path.write_text(DEEP)
    elif kind == "digits":
        path.write_text('{"T_target_source": ' + "1" * 5000 + ', "fine": 1}')
    elif kind == "huge":
        with path.open("wb") as f:
            f.truncate(11_000_000)  # sparse: no disk used
    elif kind == "socket":
        path = Path(f"/tmp/amrst-test-{os.getpid()}.sock")
        sock = socket.socket(socket.AF_UNIX)
        sock.bind(str(path))
        sock.close()
    return path


@pytest.mark.parametrize(
    ("kind", "words"),
    [
        ("loop", "symbolic link that leads back to itself"),
        ("deep", "nests brackets thousands deep"),
        ("digits", "holds a value JSON cannot be read as"),
        ("huge", "11.0 MB"),
        ("socket", "a socket, not a file"),
    ],
)
@pytest.mark.parametrize("option", ["--truth", "--params"])
def test_bad_small_files_get_their_own_line(
    capsys, sample_pair, tmp_path, kind, words, option
) -> None:
    path = _bad_file(tmp_path, kind)
    try:
        assert main(_register(sample_pair, tmp_path, option, str(path))) == 2
    finally:
        if kind == "socket":
            path.unlink()
    assert words in _one_line(capsys.readouterr().err)
    assert not (tmp_path / "out").exists()


def test_an_absurd_truth_translation_is_refused_without_warnings(
    capsys, sample_pair, tmp_path
) -> None:
    T = np.eye(4)
    T[0, 3] = 1e300
    truth = tmp_path / "truth.json"
    truth.write_text(json.dumps({"T_target_source": T.tolist()}))
    assert main(_register(sample_pair, tmp_path, "--truth", str(truth))) == 2
    assert "farther than any two scans" in _one_line(capsys.readouterr().err)


def test_list_parameters_are_range_checked_item_by_item(tmp_path) -> None:
    with pytest.raises(InvalidInput, match=r"scales_k = \[10, 100000000\]"):
        params_from_dict({"separate": {"scales_k": [10, 100000000]}})
    with pytest.raises(InvalidInput, match="has 9 values"):
        params_from_dict({"separate": {"scales_k": [10] * 9}})
    with pytest.raises(InvalidInput, match=r"seed = 1000.*\.\.\. is too large"):
        params_from_dict({"coarse": {"seed": 10**4000}})


@pytest.mark.parametrize("noise", ["1e300", "1e6"])
def test_simulate_refuses_absurd_noise(capsys, tmp_path, noise) -> None:
    tree = Path(__file__).parents[1] / "data" / "tiny_tree" / "tree.ply"
    args = ["simulate", str(tree), "--out", str(tmp_path / "case"), "--noise-m", noise]
    assert main(args) == 2
    assert "--noise-m must be a number from 0 to 0.5 m" in _one_line(
        capsys.readouterr().err
    )
    assert not (tmp_path / "case").exists()


def test_a_cloud_refuses_a_non_finite_offset() -> None:
    xyz = np.zeros((4, 3))
    for bad in ([np.inf, 0, 0], [0, np.nan, 0]):
        with pytest.raises(InvalidInput, match=r"offset .* is not finite"):
            Cloud(xyz, offset=bad)
    with pytest.raises(InvalidInput, match="3 numbers"):
        Cloud(xyz, offset=[1.0, 2.0])


def _as_unprivileged(args: list[str]) -> tuple[int, str]:
    """Run main(args) in a forked child as "nobody" (when root); return code, stderr."""
    read_end, write_end = os.pipe()
    pid = os.fork()
    if pid == 0:
        code = 99
        try:
            os.dup2(write_end, 2)
            sys.stderr = open(2, "w", closefd=False)  # noqa: SIM115 (pytest swapped it)
            if os.geteuid() == 0:
                os.setgid(65534)
                os.setuid(65534)
            code = main(args)
        except BaseException as exc:  # report, never return into pytest
            os.write(2, f"child failed: {exc!r}\n".encode())
        finally:
            sys.stderr.flush()
            os._exit(code)
    os.close(write_end)
    with os.fdopen(read_end) as f:
        err = f.read()
    _, status = os.waitpid(pid, 0)
    return os.waitstatus_to_exitcode(status), err


@pytest.fixture
def locked(tmp_path_factory) -> Path:
    """A world-reachable folder holding a folder nobody but its owner may enter."""
    import tempfile

    base = Path(tempfile.mkdtemp(prefix="amrst-perm-", dir="/tmp"))
    os.chmod(base, 0o755)
    inner = base / "private"
    inner.mkdir()
    (inner / "params.json").write_text("{}")
    (inner / "truth.json").write_text(
        json.dumps({"T_target_source": np.eye(4).tolist()})
    )
    os.chmod(inner, 0o700 if os.geteuid() == 0 else 0o000)
    yield inner
    os.chmod(inner, 0o755)
    import shutil

    shutil.rmtree(base)


@pytest.mark.skipif(not hasattr(os, "fork"), reason="POSIX")
@pytest.mark.parametrize(
    ("case", "words"),
    [
        ("params", "Permission denied reading the parameter file"),
        ("truth", "Permission denied reading the truth file"),
        ("out", "Cannot use the export folder"),
        ("simulate", "Cannot use the case folder"),
    ],
)
def test_a_folder_the_user_may_not_enter(sample_pair, locked, case, words) -> None:
    reg = ["register", str(sample_pair.target_path), str(sample_pair.source_path)]
    args = {
        "params": [*reg, "--out", "/tmp/x", "--params", str(locked / "params.json")],
        "truth": [*reg, "--out", "/tmp/x", "--truth", str(locked / "truth.json")],
        "out": [*reg, "--out", str(locked / "out")],
        "simulate": [
            "simulate",
            str(sample_pair.target_path),
            "--out",
            str(locked / "c"),
        ],
    }[case]
    code, err = _as_unprivileged(args)
    assert code == 2, err
    assert words in _one_line(err)


def test_a_scan_in_millimetres_or_snapped_coordinates_is_one_line(
    sample_pair, tmp_path, capsys
) -> None:
    from amrst import io
    from amrst.types import Cloud

    target = io.read(sample_pair.target_path)
    mm = tmp_path / "mm.ply"
    io.write(mm, Cloud(target.xyz * 1000))
    out = str(tmp_path / "o")
    assert main(["register", str(sample_pair.target_path), str(mm), "--out", out]) == 2
    assert "millimetres" in _one_line(capsys.readouterr().err)
    # float32 coordinates 5,400 km north keep half-metre steps.
    snapped = tmp_path / "snapped.ply"
    north = np.add(target.xyz, [0.0, 5.4e6, 0.0])
    io.write(snapped, Cloud(north.astype(np.float32).astype(float)))
    code = main(["register", str(snapped), str(sample_pair.source_path), "--out", out])
    assert code == 2
    assert "steps of 50 cm" in _one_line(capsys.readouterr().err)
    assert not Path(out).exists()


def test_a_sparse_scan_over_a_wide_area_is_not_taken_for_snapped() -> None:
    from amrst.io.checks import refuse_odd_coordinates
    from amrst.types import Cloud

    rng = np.random.default_rng(0)
    sparse = rng.uniform([0, 0, 0], [700, 700, 40], (2000, 3))  # airborne, 2k points
    refuse_odd_coordinates(Cloud(sparse), "als.las")
    centimetres = np.round(rng.uniform([0, 0, 0], [40, 40, 20], (200_000, 3)), 2)
    refuse_odd_coordinates(Cloud(centimetres), "coarse.las")  # a LAS scale of 1 cm


def test_stray_points_kilometres_off_a_scan_are_refused() -> None:
    from amrst.errors import InvalidInput
    from amrst.io.checks import refuse_odd_coordinates
    from amrst.types import Cloud

    rng = np.random.default_rng(1)
    scan = rng.uniform([-20, -20, 0], [20, 20, 25], (20_000, 3))
    hillside = rng.uniform([1900, 0, 0], [2000, 100, 50], (500, 3))  # 2 km: real
    refuse_odd_coordinates(Cloud(np.vstack([scan, hillside])), "far.ply")
    strays = np.array([[5e8, 0, 0], [0, -3e7, 0], [0, 0, 2e6]])  # a bad export's rows
    with pytest.raises(InvalidInput, match=r"s\.ply: 3 point\(s\) lie up to 5e\+08 m"):
        refuse_odd_coordinates(Cloud(np.vstack([scan, strays])), "s.ply")
