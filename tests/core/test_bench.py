"""Benchmark: interleaved runs, a raising method is recorded, all files are written."""

from __future__ import annotations

import argparse
import csv
import json
from pathlib import Path

import numpy as np
import pytest

from amrst.baselines import METHODS, MethodResult
from amrst.bench import TerminalProgress, configure_parser, run_bench, run_cli
from amrst.errors import Cancelled, InvalidInput
from amrst.files.atomic import write_json_atomic
from amrst.io.cases import find_cases, read_case
from amrst.types import Cloud, apply_transform, invert_transform, make_transform

TINY = Path(__file__).resolve().parents[1] / "data" / "tiny_tree" / "tree.ply"


def _make_case(folder: Path, angle_deg: float, shift, seed: int) -> np.ndarray:
    from scipy.spatial.transform import Rotation

    from amrst import io

    tree = io.read(TINY)
    rng = np.random.default_rng(seed)
    R = Rotation.from_rotvec(
        np.radians(angle_deg) * np.array([0.2, 0.3, 1.0])
    ).as_matrix()
    T = make_transform(R, shift)
    folder.mkdir(parents=True)
    src = apply_transform(invert_transform(T), tree.xyz) + rng.normal(
        0, 0.002, tree.xyz.shape
    )
    io.write(folder / "target.ply", tree)
    io.write(folder / "source.ply", Cloud(src))
    write_json_atomic(
        folder / "truth.json", {"T_target_source": T.tolist(), "seed": seed}
    )
    return T


@pytest.fixture(scope="module")
def cases_dir(tmp_path_factory) -> Path:
    root = tmp_path_factory.mktemp("cases")
    _make_case(root / "01_small", 3.0, [0.2, -0.1, 0.05], 1)
    _make_case(root / "02_other", 2.0, [-0.1, 0.15, 0.0], 2)
    (root / "not_a_case").mkdir()
    return root


def _boom(target: Cloud, source: Cloud) -> MethodResult:
    raise RuntimeError("kaboom on purpose")


def _identity(target: Cloud, source: Cloud) -> MethodResult:
    return MethodResult(np.eye(4), {"total": 0.001})


class _Recorder:
    def __init__(self, cancel_after: int | None = None) -> None:
        self.messages: list[str] = []
        self.checks = 0
        self.cancel_after = cancel_after

    def progress(self, fraction: float, message: str = "") -> None:
        self.messages.append(message)

    def check_cancelled(self) -> None:
        self.checks += 1
        if self.cancel_after is not None and self.checks > self.cancel_after:
            raise Cancelled()


def test_cases_are_found_and_read(cases_dir: Path) -> None:
    found = find_cases(cases_dir)
    assert [p.name for p in found] == ["01_small", "02_other"]
    assert [p.name for p in find_cases(cases_dir, "02*")] == ["02_other"]
    case = read_case(found[0])
    assert case.T_target_source.shape == (4, 4)
    assert len(case.target) == len(case.source) == 5000
    with pytest.raises(InvalidInput):
        read_case(cases_dir / "not_a_case")


def test_bench_survives_a_raising_method(cases_dir: Path, tmp_path: Path) -> None:
    methods = {
        "icp_centroid": METHODS["icp_centroid"],
        "boom": _boom,
        "amrst": _identity,
    }
    rec = _Recorder()
    out = tmp_path / "out"
    result = run_bench(cases_dir, methods, out, repeat=2, reporter=rec, command="x")
    assert len(result.runs) == 2 * 3 * 2
    for name in (
        "results.csv",
        "results.json",
        "summary.md",
        "accuracy.png",
        "time.png",
    ):
        assert (out / name).is_file(), name
        assert (out / name).stat().st_size > 0
    boom = [r for r in result.runs if r.method == "boom"]
    assert all("kaboom on purpose" in r.error and not r.success for r in boom)
    icp = [r for r in result.runs if r.method == "icp_centroid"]
    assert all(r.success and r.gt_rmse_m < 0.02 and not r.error for r in icp)
    assert all(r.time_s > 0 and "total" in r.timings for r in icp)
    # Interleaved: per case, repeat 0 runs the methods in order, repeat 1 rotates them.
    first_case = [(r.repeat, r.method) for r in result.runs if r.case == "01_small"]
    assert [m for rep, m in first_case if rep == 0] == ["icp_centroid", "boom", "amrst"]
    assert [m for rep, m in first_case if rep == 1] == ["boom", "amrst", "icp_centroid"]
    assert [r.case for r in result.runs[:6]] == ["01_small"] * 6
    assert rec.messages[0].startswith("case 1/2 01_small")
    summary = (out / "summary.md").read_text()
    assert "RMSE and Hausdorff distance" in summary
    assert "| case | icp_centroid RMSE | icp_centroid HD | boom RMSE" in summary
    assert "| icp_centroid | 2/2 |" in summary
    assert "| boom | 0/2 |" in summary
    assert "kaboom on purpose" in summary
    assert "Speed of amrst" in summary
    assert "CPU:" in summary
    doc = json.loads((out / "results.json").read_text())
    assert len(doc["runs"]) == 12
    assert doc["meta"]["repeat"] == 2
    with (out / "results.csv").open() as fh:
        rows = list(csv.DictReader(fh))
    assert len(rows) == 12
    assert "t_total" in rows[0]


def test_bench_cancel_keeps_partial_results(cases_dir: Path, tmp_path: Path) -> None:
    out = tmp_path / "out"
    with pytest.raises(Cancelled):
        run_bench(
            cases_dir,
            {"id": _identity},
            out,
            reporter=_Recorder(cancel_after=3),
            plots=False,
        )
    doc = json.loads((out / "results.json").read_text())
    assert 1 <= len(doc["runs"]) < 2
    assert (out / "summary.md").is_file()


def test_bench_rejects_bad_input(cases_dir: Path, tmp_path: Path) -> None:
    with pytest.raises(InvalidInput):
        run_bench(cases_dir, ["no_such_method"], tmp_path)
    with pytest.raises(InvalidInput):
        run_bench(tmp_path, ["icp"], tmp_path / "o")
    with pytest.raises(InvalidInput):
        run_bench(cases_dir, ["icp"], tmp_path / "o", repeat=0)


def test_cli_hooks(cases_dir: Path, tmp_path: Path, capsys) -> None:
    parser = argparse.ArgumentParser()
    configure_parser(parser)
    args = parser.parse_args([str(cases_dir)])
    assert args.methods == [
        "icp",
        "icp_centroid",
        "ndt",
        "fpfh_ransac",
        "fgr",
        "kiss_matcher",
        "kiss_gicp",
        "amrst",
    ]
    assert args.out == "bench_out"
    args = parser.parse_args(
        [
            str(cases_dir),
            "--methods",
            "icp",
            "--out",
            str(tmp_path / "o"),
            "--cases",
            "01*",
            "--no-plots",
        ]
    )
    assert run_cli(args) == 0
    assert "summary" in capsys.readouterr().err
    summary = tmp_path / "o" / "summary.md"
    assert summary.is_file()
    # A second run into the same folder does not replace the first's results unasked.
    summary.write_text("kept")
    assert run_cli(args) == 2
    assert "--overwrite" in capsys.readouterr().err
    assert summary.read_text() == "kept"
    args.overwrite = True
    assert run_cli(args) == 0
    assert summary.read_text() != "kept"
    bad = parser.parse_args(
        [str(cases_dir), "--methods", "nope", "--out", str(tmp_path)]
    )
    assert run_cli(bad) == 2


def test_terminal_progress_writes_a_bar() -> None:
    import io

    stream = io.StringIO()
    bar = TerminalProgress(stream, width=10)
    bar.progress(0.5, "case 1/2 x | icp")
    bar.check_cancelled()
    assert "[#####.....]" in stream.getvalue()
    assert "case 1/2 x | icp" in stream.getvalue()


def test_within_fractions_count_points_near_the_target() -> None:
    from amrst.bench.run import within_fractions

    grid = np.stack(np.meshgrid(*[np.arange(0.0, 1.0, 0.1)] * 3), -1).reshape(-1, 3)
    near = make_transform(np.eye(3), [0.03, 0.0, 0.0])  # 3 cm off every point
    far = make_transform(np.eye(3), [0.05, 0.0, 0.0])  # 5 cm: 0.1 m grid, 5 cm away
    assert within_fractions(grid, grid, [np.eye(4), near, far]) == [
        (1.0, 1.0),
        (0.0, 1.0),
        (0.0, 0.0),
    ]


def test_truth_check_says_when_the_data_prefer_the_estimate() -> None:
    from amrst.bench.headline import truth_check_markdown

    def row(success, est, true):
        return {
            "success": success,
            "error": "",
            "within_2cm": est[0],
            "within_4cm": est[1],
            "truth_within_2cm": true[0],
            "truth_within_4cm": true[1],
        }

    agg = {
        ("a", "amrst"): row(True, (0.3, 0.5), (0.3, 0.5)),
        ("b", "amrst"): row(False, (0.03, 0.10), (0.02, 0.08)),
        ("c", "amrst"): row(False, (0.01, 0.02), (0.30, 0.50)),
        ("d", "amrst"): row(False, (0.05, 0.08), (0.03, 0.10)),
        ("e", "amrst"): row(False, (0.05, 0.08), (float("nan"), float("nan"))),
    }
    text = truth_check_markdown(agg, ["a", "b", "c", "d", "e"])
    lines = {ln.split(" |")[0].strip("| "): ln for ln in text.splitlines()}
    assert lines["a"].endswith("| registered |")
    assert "at least as well as the truth" in lines["b"]
    assert "the method missed it" in lines["c"]
    assert "| 3.0% | 10.0% |" in lines["b"]
    assert "favour the estimate at 2 cm, the truth at 4 cm" in lines["d"]
    assert "n/a" in lines["e"]


def test_unreadable_cases_are_recorded_and_the_run_goes_on(
    cases_dir: Path, tmp_path: Path
) -> None:
    import shutil

    root = tmp_path / "cases"
    shutil.copytree(cases_dir / "01_small", root / "01_small")
    bad_cloud = root / "02_bad_cloud"
    shutil.copytree(cases_dir / "02_other", bad_cloud)
    (bad_cloud / "target.ply").write_bytes(b"\x00garbage" * 100)
    bad_json = root / "03_bad_json"
    shutil.copytree(cases_dir / "02_other", bad_json)
    (bad_json / "truth.json").write_text("{not json")
    not_rigid = root / "04_not_rigid"
    shutil.copytree(cases_dir / "02_other", not_rigid)
    write_json_atomic(
        not_rigid / "truth.json", {"T_target_source": (2 * np.eye(4)).tolist()}
    )
    out = tmp_path / "out"
    result = run_bench(root, {"id": _identity}, out, repeat=2, plots=False)
    assert result.cases == ["01_small", "02_bad_cloud", "03_bad_json", "04_not_rigid"]
    by_case = {c: [r for r in result.runs if r.case == c] for c in result.cases}
    assert len(by_case["01_small"]) == 2
    assert not by_case["01_small"][0].error
    reasons = {
        "02_bad_cloud": "target.ply",
        "03_bad_json": "truth.json",
        "04_not_rigid": "rigid 4x4",
    }
    for case, reason in reasons.items():
        runs = by_case[case]
        assert len(runs) == 2, case  # one failed record per method and repeat
        assert all(not r.success and reason in r.error for r in runs), case
        assert reason in result.meta["unreadable_cases"][case]
    doc = json.loads((out / "results.json").read_text())
    assert len(doc["runs"]) == 8
    summary = (out / "summary.md").read_text()
    assert "| id | 0/4 |" in summary
    assert "03_bad_json / id (repeat 0): case not read" in summary


def test_read_case_refuses_bad_truth_clearly(cases_dir: Path, tmp_path: Path) -> None:
    import shutil

    case = tmp_path / "c"
    shutil.copytree(cases_dir / "01_small", case)
    (case / "truth.json").write_text("{not json")
    with pytest.raises(InvalidInput, match="must be JSON"):
        read_case(case)
    (case / "truth.json").write_text("[1, 2]")
    with pytest.raises(InvalidInput, match="JSON object"):
        read_case(case)


def test_a_pattern_matching_nothing_says_so(cases_dir: Path, tmp_path: Path) -> None:
    with pytest.raises(InvalidInput, match=r"pattern 'zz\*' matched nothing") as exc:
        run_bench(cases_dir, {"id": _identity}, tmp_path / "o", pattern="zz*")
    assert "01_small" in str(exc.value)  # what there is to match
    assert not (tmp_path / "o").exists()
    with pytest.raises(InvalidInput, match="matched nothing"):
        run_bench(tmp_path, {"id": _identity}, tmp_path / "o", pattern="zz*")


def test_an_empty_case_folder_is_said_before_an_old_out(
    tmp_path, capsys, cases_dir
) -> None:
    parser = argparse.ArgumentParser()
    configure_parser(parser)
    out = tmp_path / "o"
    out.mkdir()
    (out / "summary.md").write_text("an earlier run")
    (tmp_path / "none").mkdir()
    args = parser.parse_args([str(tmp_path / "none"), "--out", str(out)])
    assert run_cli(args) == 2
    assert "No case folders" in capsys.readouterr().err
    args = parser.parse_args([str(cases_dir), "--cases", "zz*", "--out", str(out)])
    assert run_cli(args) == 2
    assert "matched nothing" in capsys.readouterr().err


def test_a_case_reads_its_scans_in_any_format(cases_dir: Path, tmp_path: Path) -> None:
    """target.* and source.*: any format amrst.io reads, one file a role."""
    import shutil

    from amrst import io

    case = tmp_path / "c"
    shutil.copytree(cases_dir / "01_small", case)
    source = io.read(case / "source.ply")
    io.write(case / "source.xyz", source)
    (case / "source.ply").unlink()
    (case / "notes.txt").write_text("a file of another name is not a scan")
    read = read_case(case)
    assert read.source.meta["format"] == "text"
    np.testing.assert_allclose(
        read.source.xyz + read.source.offset,
        source.xyz + source.offset,
        atol=1e-4,  # text keeps the digits it writes
    )
    result = run_bench(tmp_path, {"id": _identity}, tmp_path / "out", plots=False)
    assert [(r.case, r.error) for r in result.runs] == [("c", "")]
    io.write(case / "source.laz", source)
    with pytest.raises(InvalidInput, match=r"holds source\.laz and source\.xyz"):
        read_case(case)
    (case / "source.laz").unlink()
    (case / "source.xyz").unlink()
    with pytest.raises(InvalidInput, match=r"has no source scan: add source\.ply"):
        read_case(case)


def test_bench_refuses_an_out_inside_what_it_reads(
    cases_dir: Path, tmp_path: Path, capsys
) -> None:
    import shutil

    from amrst.cli import main

    root = tmp_path / "cases"
    shutil.copytree(cases_dir / "01_small", root / "01_small")
    for out in (root / "01_small" / "out", root / "out", root):
        assert main(["bench", str(root), "--methods", "amrst", "--out", str(out)]) == 2
        assert "choose a folder outside it" in capsys.readouterr().err
    assert sorted(p.name for p in root.iterdir()) == ["01_small"]
    assert sorted(p.name for p in (root / "01_small").iterdir()) == [
        "source.ply",
        "target.ply",
        "truth.json",
    ]
