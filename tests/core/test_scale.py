"""Scale benchmark tools: densified pairs, the timed command, bounded samples."""

from __future__ import annotations

import json
import shutil

import numpy as np
import pytest

from amrst.bench.scale import (
    densify,
    format_scale_table,
    make_scale_pair,
    time_register,
)
from amrst.errors import InvalidInput
from amrst.sampling import MEASURE_MAX_POINTS, bounded_sample, measure_pair
from amrst.types import Cloud


def _cloud(n: int = 500) -> Cloud:
    rng = np.random.default_rng(0)
    return Cloud(
        rng.uniform(0, 2, (n, 3)),
        offset=[100.0, 200.0, 0.0],
        attributes={"intensity": np.arange(n, dtype=np.uint16)},
        name="c",
    )


def test_densify_makes_jittered_copies_seeded() -> None:
    c = _cloud()
    d = densify(c, 12_345, noise_m=0.003, seed=4)
    assert len(d) == 12_345
    np.testing.assert_array_equal(d.offset, c.offset)
    src = np.arange(12_345) % len(c)
    np.testing.assert_array_equal(
        d.attributes["intensity"], c.attributes["intensity"][src]
    )
    jitter = d.xyz - c.xyz[src]
    assert jitter.std() == pytest.approx(0.003, rel=0.05)
    assert np.abs(jitter).max() < 0.003 * 6
    assert not np.any(np.all(jitter == 0, axis=1))  # no point survives exactly
    np.testing.assert_array_equal(densify(c, 12_345, 0.003, 4).xyz, d.xyz)
    assert not np.array_equal(densify(c, 12_345, 0.003, 5).xyz, d.xyz)


def test_densify_refuses_nothing_to_copy() -> None:
    with pytest.raises(InvalidInput, match="empty"):
        densify(Cloud(np.zeros((0, 3))), 10)
    with pytest.raises(InvalidInput, match="at least 1"):
        densify(_cloud(), 0)


def test_bounded_sample_is_the_cloud_itself_up_to_the_bound() -> None:
    c = _cloud(1000)
    assert bounded_sample(c, 1000) is c
    s = bounded_sample(c, 300, seed=2)
    assert len(s) == 300
    idx = s.attributes["intensity"].astype(int)  # intensity == index here
    assert np.all(np.diff(idx) > 0)  # file order, no repeats
    np.testing.assert_array_equal(s.xyz, c.xyz[idx])
    np.testing.assert_array_equal(bounded_sample(c, 300, seed=2).xyz, s.xyz)
    assert not np.array_equal(bounded_sample(c, 300, seed=3).xyz, s.xyz)


def test_measure_pair_is_the_whole_measurement_under_the_bound(sample_pair) -> None:
    """The shared cases hold at most 60,000 points a scan: measured whole, as before."""
    from amrst.measure import measure_registration

    assert max(len(sample_pair.target), len(sample_pair.source)) <= MEASURE_MAX_POINTS
    got = measure_pair(sample_pair.target, sample_pair.source, sample_pair.T_true)
    want = measure_registration(
        sample_pair.target, sample_pair.source, sample_pair.T_true
    )
    assert got == want
    few = measure_pair(
        sample_pair.target, sample_pair.source, sample_pair.T_true, max_points=2000
    )
    # The figures come from the sample; the count is still the clouds' size.
    assert few["merged"].n_points_measured == 4000
    assert few["merged"].n_points == len(sample_pair.target) + len(sample_pair.source)


@pytest.mark.slow
def test_time_register_on_a_densified_sample(tmp_path, sample_pair) -> None:
    """A dense pair written as LAZ registers in a child process: per-stage timings,
    peak memory, exit 0, and the case's truth still holds."""
    case = tmp_path / "case"
    case.mkdir()
    for p in (sample_pair.target_path, sample_pair.source_path, sample_pair.truth_path):
        shutil.copy(p, case / p.name)
    n = 3 * max(len(sample_pair.target), len(sample_pair.source))
    pair = make_scale_pair(case, tmp_path / "dense", n, seed=1)
    assert sorted(p.name for p in pair.iterdir()) == [
        "source.laz",
        "target.laz",
        "truth.json",
    ]
    truth = json.loads((pair / "truth.json").read_text())
    np.testing.assert_allclose(truth["T_target_source"], sample_pair.T_true)
    assert truth["densify_points"] == n
    row = time_register(pair)
    assert row.exit_code == 0
    assert row.n_target == n
    assert row.peak_mb > 50
    assert row.wall_s > row.timings["total"] > 0
    for stage in ("read", "preprocess", "separate", "skeleton", "fine", "metrics"):
        assert row.timings[stage] >= 0
    table = format_scale_table([row])
    assert f"{n:,}" in table
    assert table.count("\n") == 2


def test_strided_keeps_small_clouds_whole_and_spreads_over_big_ones() -> None:
    from amrst.sampling import strided

    small = np.arange(30.0).reshape(10, 3)
    np.testing.assert_array_equal(strided(small, 100), small)
    big = np.arange(3_000_000.0).reshape(-1, 3)  # 1,000,000 rows
    rows = strided(big, 200_000)
    assert len(rows) == 200_000
    np.testing.assert_array_equal(rows[:2], big[[0, 5]])
    assert rows[-1, 0] >= big[-6, 0]  # reaches the end of the sweep


def _case(tmp_path, sample_pair):
    """A copy of the bundled sample as a case folder."""
    case = tmp_path / "case"
    case.mkdir()
    for p in (sample_pair.target_path, sample_pair.source_path, sample_pair.truth_path):
        shutil.copy(p, case / p.name)
    return case


@pytest.mark.parametrize(
    ("option", "told"),
    [
        (["--noise-m", "-1"], "--noise-m must be a number from 0 to 0.5 m"),
        (["--noise-m", "nan"], "--noise-m must be a number from 0 to 0.5 m"),
        (["--noise-m", "1e30"], "--noise-m must be a number from 0 to 0.5 m"),
        (["--seed", "-1"], "--seed must be an integer of 0 or more, got -1"),
        (["--points", "2000", "10"], "--points must be an integer from 1000 to"),
        (["--points", "100000000000000"], "--points must be an integer from 1000"),
    ],
)
def test_bench_scale_refuses_bad_options_first(
    tmp_path, sample_pair, capsys, option, told
) -> None:
    from amrst.cli import main

    case = _case(tmp_path, sample_pair)
    out = tmp_path / "out"
    assert main(["bench-scale", str(case), "--out", str(out), *option]) == 2
    assert told in capsys.readouterr().err
    assert not out.exists()  # refused before anything is made


def test_bench_scale_keeps_an_earlier_run_and_says_a_failed_one(
    tmp_path, sample_pair, capsys
) -> None:
    """A dense pair amrst register refuses (its two scans the same, made before and
    reused): the run says so and exits 1; its scale.md is then replaced only with
    --overwrite."""
    from amrst.cli import main

    case = _case(tmp_path, sample_pair)
    out = tmp_path / "out"
    dense = out / "case-1000pts-noise3mm-seed0"
    dense.mkdir(parents=True)
    shutil.copy(sample_pair.source_path, dense / "target.ply")
    shutil.copy(sample_pair.source_path, dense / "source.ply")
    shutil.copy(sample_pair.truth_path, dense / "truth.json")
    argv = ["bench-scale", str(case), "--points", "1000", "--out", str(out)]
    assert main(argv) == 1
    err = capsys.readouterr().err
    assert "amrst register stopped without timings" in err
    assert f"{dense} (exit 2)" in err
    (out / "scale.md").write_text("an earlier run")
    assert main(argv) == 2
    assert "--overwrite" in capsys.readouterr().err
    assert (out / "scale.md").read_text() == "an earlier run"
    assert main([*argv, "--overwrite"]) == 1
    assert "| case-1000pts-noise3mm-seed0 | 1,000 |" in (out / "scale.md").read_text()


def test_bench_scale_checks_its_folders_before_any_work(
    tmp_path, sample_pair, capsys
) -> None:
    from amrst.cli import main

    case = _case(tmp_path, sample_pair)
    out = tmp_path / "out"
    wrong = {
        "inside the case": (
            [str(case), "--out", str(case / "dense")],
            "lies inside the case folder",
        ),
        "the case itself": ([str(case), "--out", str(case)], "is the case folder"),
        "no case": ([str(tmp_path / "nope"), "--out", str(out)], "does not exist"),
        "no truth": ([str(out.parent / "empty"), "--out", str(out)], "no truth.json"),
        "kiss": (
            [str(case), "--out", str(out), "--kiss", str(tmp_path / "nope")],
            "does not exist",
        ),
    }
    (tmp_path / "empty").mkdir()
    for name, (argv, told) in wrong.items():
        assert main(["bench-scale", *argv, "--points", "2000"]) == 2, name
        err = capsys.readouterr().err
        assert told in err, name
        assert "making" not in err, name
        assert not out.exists(), name
        assert not (case / "dense").exists(), name


def test_kiss_ratio_skips_a_case_it_cannot_read(tmp_path, sample_pair, caplog) -> None:
    pytest.importorskip("kiss_matcher")
    from amrst.bench.kiss import kiss_ratio

    cases = tmp_path / "cases"
    cases.mkdir()
    good = _case(cases, sample_pair)
    broken = cases / "broken"
    shutil.copytree(good, broken)
    (broken / "target.ply").write_text("not a point cloud")
    rows = kiss_ratio([str(cases)])
    assert [r.case for r in rows] == ["case"]
    assert "broken skipped:" in caplog.text
