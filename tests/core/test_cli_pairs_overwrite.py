"""amrst register --pairs, and no silent overwrite of another pair's export."""

from __future__ import annotations

import json
import shutil

import numpy as np

from amrst.cli import main
from amrst.review.pairs_file import write_pairs


def _register(*args: str) -> int:
    return main(["register", *args, "--quiet"])


def test_an_export_of_another_pair_is_kept_unless_overwrite(
    tmp_path, sample_pair, capsys
) -> None:
    t, s = str(sample_pair.target_path), str(sample_pair.source_path)
    out = tmp_path / "out"
    assert _register(t, s, "--out", str(out)) == 0
    first = (out / "transform.json").read_bytes()
    other = tmp_path / "other_source.ply"
    shutil.copyfile(s, other)
    capsys.readouterr()
    assert _register(t, str(other), "--out", str(out)) == 2
    err = capsys.readouterr().err.strip()
    assert "--overwrite" in err
    assert len(err.splitlines()) == 1
    assert (out / "transform.json").read_bytes() == first
    # Several scans keep it too (they once wrote over any folder).
    assert _register(t, s, str(other), "--out", str(out)) == 2
    assert "the export of source.ply onto target.ply" in capsys.readouterr().err
    assert (out / "transform.json").read_bytes() == first
    assert _register(t, s, "--out", str(out)) == 0  # the same pair again
    assert _register(t, str(other), "--out", str(out), "--overwrite") == 0
    doc = json.loads((out / "transform.json").read_text())
    assert doc["source_file"] == str(other)


def test_files_of_another_kind_of_run_are_kept_unless_overwrite(
    tmp_path, sample_pair, capsys
) -> None:
    t, s = str(sample_pair.target_path), str(sample_pair.source_path)
    for name, says in (
        ("plot.json", "a forest plot's results"),
        ("report.html", "report.html of another run"),
    ):
        out = tmp_path / name.replace(".", "_")
        out.mkdir()
        (out / name).write_text("{}")  # a plot's results, or a report of some run
        capsys.readouterr()
        assert _register(t, s, "--out", str(out), "--report") == 2
        err = capsys.readouterr().err.strip()
        assert says in err
        assert "--overwrite" in err
        assert (out / name).read_text() == "{}"
        assert _register(t, s, "--out", str(out), "--report", "--overwrite") == 0
        assert (out / "transform.json").is_file()


def test_a_scan_in_the_folder_under_an_output_name_is_never_written_over(
    tmp_path, sample_pair, capsys
) -> None:
    out = tmp_path / "out"
    out.mkdir()
    for name in ("merged.ply", "report.html", "transform_1.txt"):
        scan = out / name
        shutil.copyfile(sample_pair.target_path, scan)
        before = scan.read_bytes()
        s = str(sample_pair.source_path)
        capsys.readouterr()
        # transform_1.txt is written by a run of several scans only.
        several = "transform_" in name
        sources = [s, str(sample_pair.target_path)] if several else [s]
        code = _register(str(scan), *sources, "--out", str(out), "--overwrite")
        assert code == 2
        err = capsys.readouterr().err
        assert "is a file the run writes in" in err
        assert scan.read_bytes() == before
        # Nor through a link to it from elsewhere.
        link = tmp_path / f"link_{name}"
        link.symlink_to(scan)
        capsys.readouterr()
        assert _register(str(link), *sources, "--out", str(out), "--overwrite") == 2
        assert "is a file the run writes in" in capsys.readouterr().err
        assert scan.read_bytes() == before
        scan.unlink()


def _register_from_pairs(tmp_path, sample_pair, *args: str, off_m: float = 0.0) -> int:
    """Register the sample pair from four pairs picked on the truth, ``off_m`` off."""
    src = sample_pair.source.xyz + sample_pair.source.offset
    picked = src[[0, len(src) // 3, 2 * len(src) // 3, len(src) - 1]]
    T = sample_pair.T_true
    target = picked @ T[:3, :3].T + T[:3, 3] + (off_m, 0.0, 0.0)
    write_pairs(tmp_path / "pairs.csv", target, picked)
    return _register(
        str(sample_pair.target_path),
        str(sample_pair.source_path),
        "--out",
        str(tmp_path / "out"),
        "--pairs",
        str(tmp_path / "pairs.csv"),
        *args,
    )


def test_register_from_a_pairs_file(tmp_path, sample_pair, capsys) -> None:
    code = _register_from_pairs(
        tmp_path, sample_pair, "--truth", str(sample_pair.truth_path)
    )
    out = capsys.readouterr().out
    assert code == 0
    assert "(point pairs)" in out
    metrics = json.loads((tmp_path / "out" / "metrics.json").read_text())
    assert metrics["truth"]["fine"]["rotation_error_deg"] < 0.5
    assert metrics["coarse"]["candidate_origin"] == "manual"
    assert np.isfinite(metrics["quality"]["distance"]["median_m"])


def test_a_bad_pairs_file_is_one_line_and_exit_2(tmp_path, sample_pair, capsys):
    (tmp_path / "pairs.csv").write_text("x,y\n1,2\n")
    code = _register(
        str(sample_pair.target_path),
        str(sample_pair.source_path),
        "--out",
        str(tmp_path / "out"),
        "--pairs",
        str(tmp_path / "pairs.csv"),
    )
    err = capsys.readouterr().err.strip()
    assert code == 2
    assert "target_x" in err
    assert len(err.splitlines()) == 1


def test_a_pose_that_needs_review_exits_3(tmp_path, sample_pair, capsys) -> None:
    # Pairs picked 30 cm off and no fine stage: a pose close enough to look right but
    # not verified; a script must not take it as registered.
    params = tmp_path / "params.json"
    params.write_text(
        '{"schema_version": 1, "fine": {"method": "none"}, "coarse": {"polish_top": 0}}'
    )
    code = _register_from_pairs(
        tmp_path, sample_pair, "--params", str(params), off_m=0.3
    )
    err = capsys.readouterr().err
    assert "Needs review" in err
    assert code == 3


def test_a_truth_or_params_file_under_an_output_name_is_never_written_over(
    tmp_path, sample_pair, capsys
) -> None:
    out = tmp_path / "out"
    out.mkdir()
    t, s = str(sample_pair.target_path), str(sample_pair.source_path)
    truth = out / "transform.json"  # the truth where the run writes its transform
    shutil.copyfile(sample_pair.target_path.parent / "truth.json", truth)
    before = truth.read_bytes()
    assert _register(t, s, "--out", str(out), "--truth", str(truth), "--overwrite") == 2
    assert f"{truth} is a file the run writes in" in capsys.readouterr().err
    assert truth.read_bytes() == before
    truth.unlink()
    params = out / "params.json"
    params.write_text("{}")
    assert (
        _register(t, s, "--out", str(out), "--params", str(params), "--overwrite") == 2
    )
    assert f"{params} is a file the run writes in" in capsys.readouterr().err
    assert params.read_text() == "{}"
