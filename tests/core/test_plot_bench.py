"""``amrst bench`` on plot cases: tree matching, inventory scores, and a whole run."""

from __future__ import annotations

import json
from typing import TYPE_CHECKING

import numpy as np
import pytest
from _plots import STEMS, pose, scan

from amrst.bench.plot import (
    KISS,
    PLOT,
    is_plot_case,
    match_trees,
    read_plot_case,
    run_plot_bench,
    score_inventory,
)
from amrst.errors import InvalidInput
from amrst.types import Cloud, invert_transform

if TYPE_CHECKING:
    from pathlib import Path

NAN = float("nan")


def test_each_true_tree_is_matched_once_closest_first() -> None:
    true_xy = np.array([[0.0, 0.0], [5.0, 0.0]])
    listed = np.array([[0.3, 0.0], [0.1, 0.0], [5.6, 0.0], [9.0, 9.0]])
    assert sorted(match_trees(listed, true_xy)) == [(1, 0)]
    assert match_trees(listed[:0], true_xy) == []


def test_inventory_score_uses_defined_truth_only() -> None:
    truth = np.array([[0, 0, 0, 0.30, 20.0], [5, 0, 0, NAN, 15.0], [9, 0, 0, 0.2, 9.0]])
    listed = np.array(
        [[0.1, 0, 0, 0.32, 19.5], [5.1, 0, 0, 0.5, 16.0], [9, 0, 0, NAN, 9.2]]
    )
    s = score_inventory(listed, ["ok", "check", "check"], truth, ["ok", "lean", "ok"])
    assert (s.n_true, s.found, s.listed, s.real) == (3, 3, 3, 3)
    assert np.allclose(s.dbh_errors_m, [0.02])
    assert np.allclose(s.dbh_ok_errors_m, [0.02])
    assert s.dbh_missing == 1
    assert np.allclose(sorted(s.height_errors_m), [-0.5, 0.2, 1.0])
    assert np.allclose(sorted(s.height_ok_errors_m), [-0.5, 0.2])


def _sparse_ground(xyz: np.ndarray) -> np.ndarray:
    """Every fourth ground point (the feature baseline's time grows with the area)."""
    ground = xyz[:, 2] < 0.03 * xyz[:, 0] - 0.02 * xyz[:, 1] + 0.01
    return xyz[~ground | (np.arange(len(xyz)) % 4 == 0)]


def _plot_case(folder: Path) -> None:
    from amrst import io

    folder.mkdir(parents=True)
    T = pose(70.0, (3.0, 1.0, 0.0), tilt_deg=1.0)
    io.write(folder / "target.ply", Cloud(_sparse_ground(scan((-2.0, 0.0), STEMS, 1))))
    world = _sparse_ground(scan((3.0, 1.0), STEMS, 2))
    inv = invert_transform(T)
    io.write(folder / "source.ply", Cloud(world @ inv[:3, :3].T + inv[:3, 3]))
    z = 0.03 * np.array([s[0] for s in STEMS]) - 0.02 * np.array([s[1] for s in STEMS])
    stems = [
        {"x": x, "y": y, "z_base": float(zb), "dbh_m": 2 * r, "height_m": h}
        for (x, y, r, h), zb in zip(STEMS, z, strict=True)
    ]
    doc = {
        "T_scan1_scank": [np.eye(4).tolist(), T.tolist()],
        "stems_target_frame": stems,
    }
    (folder / "truth.json").write_text(json.dumps(doc))


def test_bench_recognises_plot_cases_and_scores_the_methods(tmp_path: Path) -> None:
    root = tmp_path / "cases"
    _plot_case(root / "01_plot")
    (root / "02_empty").mkdir()
    assert is_plot_case(root / "01_plot")
    assert not is_plot_case(root / "02_empty")
    _plot_case(root / "00_cut")  # a scan cut short: skipped, the others run
    data = (root / "00_cut" / "source.ply").read_bytes()
    (root / "00_cut" / "source.ply").write_bytes(data[: len(data) // 2])
    out = tmp_path / "out"
    # FPFH + RANSAC runs in the command's default set; its time on this plot is long.
    records = run_plot_bench(root, out, methods=(PLOT, KISS))
    assert [r.method for r in records] == [PLOT, KISS]
    assert "- 00_cut skipped: " in (out / "summary.md").read_text()
    with pytest.raises(InvalidInput, match="No plot case could be read"):
        run_plot_bench(root / "00_cut", tmp_path / "none", methods=(PLOT,))
    plot = json.loads((out / "plot_results.json").read_text())[0]
    assert plot["registered"] == 1
    assert plot["inventory"]["found"] == len(STEMS)
    assert plot["inventory"]["listed"] == len(STEMS)
    assert np.sqrt(np.mean(np.square(plot["inventory"]["dbh_errors_m"]))) < 0.01
    summary = (out / "summary.md").read_text()
    assert "| 01_plot | 2 |" in summary
    assert "trees found: 6/6" in summary
    # The residual tells the last scan's true pose from one 1 deg and 10 cm off.
    assert len(plot["residuals_m"]) == 2
    assert plot["residual_off_m"] > 2 * plot["residual_true_m"] > 0
    assert "## Scan residuals (amrst plot)" in summary
    with pytest.raises(InvalidInput, match="Unknown plot method"):
        run_plot_bench(root, out, methods=("icp",))
    from amrst.cli import main

    for wrong in (
        ["--repeat", "0"],
        ["--repeat", "-1"],
        ["--repeat", "1000000000"],  # days of runs: refused, not started
        ["--methods", "nosuch"],
    ):
        assert main(["bench", str(root), "--out", str(tmp_path / "o2"), *wrong]) == 2
        assert not (tmp_path / "o2").exists()


def _small_plot_case(folder: Path, stems: object) -> None:
    """Two small scans and a truth whose stem list is ``stems`` (as JSON)."""
    from amrst import io

    folder.mkdir(parents=True)
    rng = np.random.default_rng(0)
    for name in ("target", "source"):
        io.write(folder / f"{name}.ply", Cloud(rng.uniform(-5, 5, (500, 3))))
    doc = {"T_scan1_scank": [np.eye(4).tolist()] * 2, "stems_target_frame": stems}
    (folder / "truth.json").write_text(json.dumps(doc))


GOOD_STEM = {"x": 1.0, "y": 2.0, "z_base": 0.0, "dbh_m": None, "height_m": 9.0}


@pytest.mark.parametrize(
    ("stems", "told"),
    [
        ([{**GOOD_STEM, "x": "x"}], 'stem 1 of stems_target_frame has x "x"'),
        ([GOOD_STEM, {"y": 2.0}], "stem 2 of stems_target_frame has no x"),
        ([{**GOOD_STEM, "height_m": "tall"}], 'has height_m "tall"'),
        ([{**GOOD_STEM, "z_base": None}], "has z_base null"),
        ([{**GOOD_STEM, "dbh_m": True}], "has dbh_m true"),
        ([1, 2, 3], "stem 1 of stems_target_frame is 1;"),
        ({"x": 1.0}, "stems_target_frame must be a list"),
    ],
)
@pytest.mark.parametrize("command", ["bench", "bench-scale"])
def test_a_bad_stem_list_is_told_in_one_line(
    tmp_path: Path, capsys, stems: object, told: str, command: str
) -> None:
    """Both commands read the truth in one place: the case and what is wrong."""
    from amrst.cli import main

    _small_plot_case(tmp_path / "cases" / "01_plot", stems)
    given = tmp_path / "cases" if command == "bench" else tmp_path / "cases/01_plot"
    argv = [command, str(given), "--out", str(tmp_path / "out")]
    assert main([*argv, "--points", "1000"] if command != "bench" else argv) == 2
    err = capsys.readouterr().err.strip().splitlines()[-1]
    assert f"{tmp_path / 'cases' / '01_plot' / 'truth.json'}: " in err
    assert told in err


def test_a_stem_without_a_dbh_is_read_as_nan(tmp_path: Path) -> None:
    stems = [GOOD_STEM, {**GOOD_STEM, "dbh_m": 0.3}, {**GOOD_STEM, "dbh_m": NAN}]
    _small_plot_case(tmp_path / "p", stems)
    case = read_plot_case(tmp_path / "p")
    np.testing.assert_array_equal(case.stems[:, 3], [NAN, 0.3, NAN])
    np.testing.assert_array_equal(case.stems[0], [1.0, 2.0, 0.0, NAN, 9.0])


def test_plot_cases_among_tree_pairs_are_refused_not_run_as_pairs(
    tmp_path: Path, capsys
) -> None:
    from amrst.cli import main

    _small_plot_case(tmp_path / "cases" / "01_plot", [GOOD_STEM])
    pair = tmp_path / "cases" / "02_pair"
    pair.mkdir()
    (pair / "truth.json").write_text('{"T_target_source": "not read"}')
    out = tmp_path / "out"
    assert main(["bench", str(tmp_path / "cases"), "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert "holds 1 plot case(s) among 2" in err
    assert "--cases PATTERN" in err
    assert not out.exists()
