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
from amrst.errors import InvalidInput

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
    assert line.startswith("amrst info: ")
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
    assert "amrst plot" not in proc.stdout  # one tree: no plot to point to
    doc = json.loads((out / "transform.json").read_text(encoding="utf-8"))
    T = np.asarray(doc["T_target_source"], dtype=float)
    assert T.shape == (4, 4)
    np.testing.assert_allclose(T[3], [0, 0, 0, 1])
    assert np.linalg.det(T[:3, :3]) == pytest.approx(1.0)
    assert np.asarray(doc["T_coarse"]).shape == (4, 4)
    assert doc["amrst_version"] == amrst.__version__
    metrics = json.loads((out / "metrics.json").read_text(encoding="utf-8"))
    # One layout, from amrst.results.documents.result_documents.
    assert doc["schema_version"] == metrics["schema_version"] == 2
    assert doc["timings_s"]["read"] > 0
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
    from amrst.errors import EXIT_NOT_REGISTERED
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
    assert rc == EXIT_NOT_REGISTERED
    assert "Traceback" not in err
    assert "Registration failed" in err
    if (out / "transform.json").exists():  # written for inspection, never as a success
        assert json.loads((out / "transform.json").read_text())["verified"] is False


def _no_registration(monkeypatch) -> None:
    """Make any registration fail the test: the checks must come before it."""
    import amrst.pipeline

    def register(*args, **kwargs):
        raise AssertionError("registered although the command line was refused")

    monkeypatch.setattr(amrst.pipeline, "register", register)


def _rot(deg: float) -> np.ndarray:
    a = np.radians(deg)
    return np.array([[np.cos(a), -np.sin(a), 0], [np.sin(a), np.cos(a), 0], [0, 0, 1]])


def _with(R, t=(1.0, 2.0, 0.5), last=(0.0, 0.0, 0.0, 1.0)) -> list:
    T = np.eye(4)
    T[:3, :3], T[:3, 3], T[3] = R, t, last
    return T.tolist()


@pytest.mark.parametrize(
    ("matrix", "says"),
    [
        (np.zeros((4, 4)).tolist(), "last row"),
        (_with(_rot(20) @ np.diag([1.0, 1.0, -1.0])), "reflection"),
        (_with(2.0 * np.eye(3)), "not a rotation"),
        (_with(np.eye(3), last=(0, 0, 0, 2)), "last row"),
        (_with([[1, 0.5, 0], [0, 1, 0], [0, 0, 1]]), "not a rotation"),
        (_with(np.eye(3), last=(1, 1, 1, 1)), "last row"),
        (_with(np.eye(3), t=(float("nan"), 0, 0)), "contains NaN/inf"),
    ],
)
def test_truth_must_be_a_rigid_transform(
    capsys, monkeypatch, tmp_path, sample_pair, matrix, says
) -> None:
    _no_registration(monkeypatch)
    truth = tmp_path / "truth.json"
    truth.write_text(json.dumps({"T_target_source": matrix}))  # NaN written as NaN
    out = tmp_path / "out"
    t, s = str(sample_pair.target_path), str(sample_pair.source_path)
    assert main(["register", t, s, "--out", str(out), "--truth", str(truth)]) == 2
    line = _one_line_error(capsys.readouterr().err)
    assert says in line
    assert "rigid 4x4 transform" in line
    assert "got shape (4, 4)" not in line
    assert not out.exists()


def test_a_valid_truth_is_accepted(tmp_path) -> None:
    from amrst.io.truth import read_truth

    truth = tmp_path / "truth.json"
    T = _with(_rot(33.0), t=(-9.9, 7.2, 0.01))
    truth.write_text(json.dumps({"T_target_source": T}))
    np.testing.assert_array_equal(read_truth(str(truth)), np.asarray(T))
    with pytest.raises(InvalidInput, match="is a folder"):
        read_truth(str(tmp_path))


def test_bad_output_folder_is_refused_before_registering(
    capsys, monkeypatch, tmp_path, sample_pair
) -> None:
    _no_registration(monkeypatch)
    t, s = str(sample_pair.target_path), str(sample_pair.source_path)
    a_file = tmp_path / "a_file"
    a_file.write_text("x")
    cases = {str(a_file): "existing file", str(a_file / "sub"): "a file"}
    if Path("/proc/self").is_dir():  # Linux: no folder can be made in /proc
        cases["/proc/amrst-test"] = "Cannot create the export folder"
    for out, says in cases.items():
        assert main(["register", t, s, "--out", out, "--quiet"]) == 2, out
        assert says in _one_line_error(capsys.readouterr().err), out
    # A file name taken by a folder is found before registering too.
    out = tmp_path / "out"
    (out / "merged.ply").mkdir(parents=True)
    rc = main(["register", t, s, "--out", str(out), "--write-clouds", "--quiet"])
    assert rc == 2
    assert "merged.ply" in _one_line_error(capsys.readouterr().err)
    assert sorted(p.name for p in out.iterdir()) == ["merged.ply"]


def test_preset_and_params_are_exclusive(capsys, monkeypatch, tmp_path, sample_pair):
    from amrst.params import RegistrationParams, list_presets, save_params

    _no_registration(monkeypatch)
    params = tmp_path / "params.json"
    save_params(params, RegistrationParams())
    t, s, out = str(sample_pair.target_path), str(sample_pair.source_path), "o"
    preset = sorted(list_presets())[0]
    args = ["register", t, s, "--out", str(tmp_path / out)]
    assert main([*args, "--preset", preset, "--params", str(params)]) == 2
    assert "use one of --preset or --params" in _one_line_error(capsys.readouterr().err)
    # An unknown preset is an error listing the known ones, with --params too.
    assert main([*args, "--preset", "nosuch", "--params", str(params)]) == 2
    line = _one_line_error(capsys.readouterr().err)
    assert "No preset named 'nosuch'" in line
    assert all(name in line for name in list_presets())


def test_stale_clouds_of_an_earlier_run_are_removed(
    caplog, capsys, tmp_path, sample_pair
) -> None:
    out = tmp_path / "out"
    t, s = str(sample_pair.target_path), str(sample_pair.source_path)
    # An earlier run of the pair wrote its clouds (and, once, LAS ones) and a report.
    first = ["register", t, s, "--out", str(out), "--quiet", "--write-clouds"]
    assert main([*first, "--report"]) == 0
    stale = ["registered_source.ply", "merged.ply", "merged.las", "report.html"]
    kept = ["notes.txt", "merged_old.ply"]  # not AMRST output names: left alone
    for name in ["merged.las", *kept]:
        (out / name).write_bytes(b"earlier run")
    with caplog.at_level("WARNING"):
        assert main(["register", t, s, "--out", str(out), "--quiet"]) == 0
    names = sorted(p.name for p in out.iterdir())
    assert not set(stale) & set(names)
    assert set(kept) <= set(names)
    assert "transform.json" in names
    lines = [r.getMessage() for r in caplog.records if "earlier run" in r.getMessage()]
    assert len(lines) == 1
    assert all(name in lines[0] for name in stale)


def test_report_is_written_with_the_result_or_not_at_all(
    capsys, monkeypatch, tmp_path, sample_pair
) -> None:
    # The report belongs to the result's set: a report that cannot be drawn leaves
    # the earlier set whole, its report included, not a new result without one.
    import amrst.results.report_html as report_html
    from amrst.errors import AmrstError

    out = tmp_path / "out"
    t, s = str(sample_pair.target_path), str(sample_pair.source_path)
    args = ["register", t, s, "--out", str(out), "--quiet", "--report"]
    assert main(args) == 0
    before = {p.name: p.read_bytes() for p in out.iterdir()}
    assert "report.html" in before

    def fail(_inputs):
        raise AmrstError("cannot draw the pictures")

    monkeypatch.setattr(report_html, "render_images", fail)
    assert main(args) != 0
    assert "cannot draw the pictures" in capsys.readouterr().err
    assert {p.name: p.read_bytes() for p in out.iterdir()} == before


def test_one_scan_as_target_and_source_is_refused(capsys, tmp_path, sample_pair):
    # Registering a scan onto itself tells nothing, and verifying the identity on
    # a big scan took minutes: the same file, or a copy of it, is bad input.
    t = str(sample_pair.target_path)
    copy = tmp_path / "copy.ply"
    copy.write_bytes(sample_pair.target_path.read_bytes())
    for source in (t, str(copy)):
        out = tmp_path / "o"
        assert main(["register", t, source, "--out", str(out), "--quiet"]) == 2
        err = capsys.readouterr().err
        assert "same file" in err or "holds the same points" in err
        assert len(err.strip().splitlines()) == 1
        assert not (out / "transform.json").exists()


def test_a_cloud_format_without_clouds_is_refused(capsys, tmp_path, sample_pair):
    t, s = str(sample_pair.target_path), str(sample_pair.source_path)
    out = tmp_path / "o"
    assert main(["register", t, s, "--out", str(out), "--format", "las"]) == 2
    err = capsys.readouterr().err
    assert "--format las sets the format of the clouds --write-clouds writes" in err
    assert len(err.strip().splitlines()) == 1
    assert not out.exists()


def test_closed_output_pipe_ends_quietly(sample_pair) -> None:
    """``amrst info big.ply | head -1``: no BrokenPipeError traceback."""
    assert VENV_AMRST.is_file(), f"console script missing: {VENV_AMRST}"
    read_end, write_end = os.pipe()
    proc = subprocess.Popen(
        [str(VENV_AMRST), "info", str(sample_pair.target_path)],
        stdout=write_end,
        stderr=subprocess.PIPE,
    )
    os.close(write_end)
    os.close(read_end)  # the reader is gone before amrst writes anything
    _, err = proc.communicate(timeout=120)
    text = err.decode()
    assert "Traceback" not in text
    assert "BrokenPipeError" not in text
    assert "Exception ignored" not in text
    assert proc.returncode == 1


def test_a_file_system_refusal_is_one_line_not_an_internal_error(
    capsys, tmp_path
) -> None:
    """A file name too long for the file system is refused in a line, not an OSError."""
    too_long = tmp_path / ("a" * 300 + ".ply")
    assert main(["info", str(too_long)]) == EXIT_INPUT
    line = _one_line_error(capsys.readouterr().err)
    # The reader names the file and what to do; the CLI's own net says the same
    # without a path when a check point is missed.
    assert line.startswith("amrst info: ")
    assert "File name too long" in line
    assert "Internal error" not in line


def test_a_stem_that_is_no_position_in_the_scan_is_refused(
    capsys, tmp_path, sample_pair
):
    t, s = str(sample_pair.target_path), str(sample_pair.source_path)
    for stem in (["nan", "nan"], ["inf", "0"], ["500", "500"]):
        args = ["register", t, s, "--out", str(tmp_path / "o"), "--quiet"]
        assert main([*args, "--stem", *stem]) == 2
        err = capsys.readouterr().err
        assert "The stem of the target" in err
        assert len(err.strip().splitlines()) == 1


def test_info_on_one_scan_of_a_file_says_how_to_see_its_scans(capsys, sample_pair):
    t = str(sample_pair.target_path)
    assert main(["info", f"{t}#5"]) == 2
    err = capsys.readouterr().err
    assert "holds one scan; '#' selects scans of E57 and PTX files only" in err
    assert "File not found" not in err


def test_a_wrong_argument_is_one_line(capsys) -> None:
    with pytest.raises(SystemExit) as exc:
        main(["register", "a.ply", "b.ply"])
    assert exc.value.code == 2
    line = _one_line_error(capsys.readouterr().err)
    assert line == (
        "amrst register: the following arguments are required: --out "
        "(amrst register --help lists them)."
    )


def test_an_empty_argument_is_refused_before_it_names_the_current_folder(
    capsys,
) -> None:
    for argv in (["info", ""], ["plot", "", "b.ply", "--out", "o"], ["bench", ""]):
        with pytest.raises(SystemExit) as exc:
            main(argv)
        assert exc.value.code == 2
        assert "an empty argument was given" in _one_line_error(capsys.readouterr().err)
