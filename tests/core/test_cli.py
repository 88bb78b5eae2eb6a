"""The ``amrst`` command: in-process through main(), and one real subprocess run."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

import amrst
from amrst.cli import EXIT_INPUT, main

VENV_AMRST = Path(sys.executable).with_name("amrst")


def _one_line_error(err: str) -> str:
    lines = [line for line in err.splitlines() if line.strip()]
    assert len(lines) == 1, f"expected one line on stderr, got:\n{err}"
    assert "Traceback" not in err
    return lines[0]


def test_version(capsys) -> None:
    with pytest.raises(SystemExit) as exc:
        main(["--version"])
    assert exc.value.code == 0
    assert capsys.readouterr().out.strip() == f"amrst {amrst.__version__}"


def test_no_command_prints_help(capsys) -> None:
    assert main([]) == 0
    out = capsys.readouterr().out
    for command in ("info", "register", "simulate", "bench"):
        assert command in out


def test_info_prints_the_point_count(capsys, sample_pair) -> None:
    assert main(["info", str(sample_pair.target_path)]) == 0
    out = capsys.readouterr().out
    assert "target.ply" in out
    assert f"{len(sample_pair.target):,}" in out  # 7,024
    assert "points" in out


def test_info_on_two_files(capsys, sample_pair) -> None:
    code = main(["info", str(sample_pair.target_path), str(sample_pair.source_path)])
    assert code == 0
    out = capsys.readouterr().out
    assert f"{len(sample_pair.target):,}" in out
    assert f"{len(sample_pair.source):,}" in out


def test_missing_file_exits_2_with_one_line(capsys, tmp_path) -> None:
    missing = tmp_path / "nope.ply"
    assert main(["info", str(missing)]) == EXIT_INPUT == 2
    line = _one_line_error(capsys.readouterr().err)
    assert line.startswith("Error:")
    assert "nope.ply" in line


def test_corrupt_file_exits_2(capsys, tmp_path, sample_pair) -> None:
    garbage = tmp_path / "scan.ply"
    garbage.write_bytes(np.random.default_rng(0).bytes(4096))
    assert main(["info", str(garbage)]) == 2
    assert "scan.ply" in _one_line_error(capsys.readouterr().err)
    # register refuses it too, before any work, and writes nothing.
    out = tmp_path / "out"
    code = main(
        ["register", str(sample_pair.target_path), str(garbage), "--out", str(out)]
    )
    assert code == 2
    _one_line_error(capsys.readouterr().err)
    assert not out.exists()


def test_bad_truth_and_params_exit_2(capsys, tmp_path, sample_pair) -> None:
    t, s = str(sample_pair.target_path), str(sample_pair.source_path)
    bad_truth = tmp_path / "truth.json"
    bad_truth.write_text(json.dumps({"T_target_source": [[1, 0], [0, 1]]}))
    out = str(tmp_path / "out")
    assert main(["register", t, s, "--out", out, "--truth", str(bad_truth)]) == 2
    assert "4x4" in _one_line_error(capsys.readouterr().err)
    bad_params = tmp_path / "params.json"
    bad_params.write_text(json.dumps({"fine": {"no_such_knob": 1}}))
    assert main(["register", t, s, "--out", out, "--params", str(bad_params)]) == 2
    assert "no_such_knob" in _one_line_error(capsys.readouterr().err)
    assert main(["register", t, s, "--out", out, "--preset", "nope"]) == 2
    assert "No preset named" in _one_line_error(capsys.readouterr().err)


@pytest.mark.slow
def test_register_subprocess_writes_transform_and_truth_errors(
    tmp_path, sample_pair
) -> None:
    assert VENV_AMRST.is_file(), f"console script missing: {VENV_AMRST}"
    out = tmp_path / "out"
    proc = subprocess.run(
        [
            str(VENV_AMRST),
            "register",
            str(sample_pair.target_path),
            str(sample_pair.source_path),
            "--truth",
            str(sample_pair.truth_path),
            "--out",
            str(out),
            "--quiet",
        ],
        capture_output=True,
        text=True,
        timeout=240,
        env={**os.environ, "PYTHONWARNINGS": "error"},
        check=False,
    )
    assert proc.returncode == 0, proc.stderr
    assert "Traceback" not in proc.stderr
    assert "Registered source.ply onto target.ply" in proc.stdout
    doc = json.loads((out / "transform.json").read_text(encoding="utf-8"))
    T = np.asarray(doc["T_target_source"], dtype=float)
    assert T.shape == (4, 4)
    np.testing.assert_allclose(T[3], [0, 0, 0, 1])
    assert np.linalg.det(T[:3, :3]) == pytest.approx(1.0)
    assert np.asarray(doc["T_coarse"]).shape == (4, 4)
    assert doc["amrst_version"] == amrst.__version__
    metrics = json.loads((out / "metrics.json").read_text(encoding="utf-8"))
    truth = metrics["truth"]
    for stage in ("fine", "coarse"):
        assert {"rotation_error_deg", "translation_error_m", "gt_rmse_m"} <= set(
            truth[stage]
        )
    assert isinstance(truth["registered"], bool)
    # The truth errors written are those of the transform written.
    from scipy.spatial.transform import Rotation

    R_err = T[:3, :3] @ sample_pair.T_true[:3, :3].T
    rot = np.degrees(Rotation.from_matrix(R_err).magnitude())
    assert truth["fine"]["rotation_error_deg"] == pytest.approx(rot, abs=1e-5)
    assert truth["coarse"]["rotation_error_deg"] < 2.0
    assert (out / "params.json").is_file()
    assert (out / "metrics.csv").is_file()
    assert not (out / "merged.ply").exists()  # only with --write-clouds


def test_unregistrable_pair_exits_3_and_marks_files_unverified(
    capsys, tmp_path, sample_pair
) -> None:
    # A box of random points is not the same tree: no transform may be reported as found.
    from amrst import io
    from amrst.cli import EXIT_FAILED
    from amrst.types import Cloud

    rng = np.random.default_rng(5)
    src = tmp_path / "noise.ply"
    io.write(src, Cloud(rng.uniform([0, 0, 0], [6, 6, 20], size=(8000, 3))))
    out = tmp_path / "out"
    rc = main(
        [
            "register",
            str(sample_pair.target_path),
            str(src),
            "--out",
            str(out),
            "--quiet",
        ]
    )
    err = capsys.readouterr().err
    assert rc == EXIT_FAILED
    assert "Traceback" not in err
    assert "Registration failed" in err
    if (out / "transform.json").exists():  # written for inspection, never as a success
        assert json.loads((out / "transform.json").read_text())["verified"] is False
