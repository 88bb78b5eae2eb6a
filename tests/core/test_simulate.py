"""The virtual scanner: exact truth, occlusion, frames, determinism, case files."""

from __future__ import annotations

import argparse
import json

import numpy as np
import pytest

from amrst.io.cases import read_case
from amrst.simulate import (
    simulate_pair,
    simulate_scan,
    trunk_base,
    write_case,
)
from amrst.simulate.cli import configure_parser, run_cli
from amrst.types import (
    Cloud,
    apply_transform,
    invert_transform,
    rotation_angle_deg,
)

CASE_KEYS = {
    "T_target_source",
    "spec_target",
    "spec_source",
    "tree",
    "seed",
    "n_target",
    "n_source",
}


@pytest.fixture(scope="module")
def tree() -> Cloud:
    """A synthetic tree: a 0.2 m trunk 6 m tall and a crown ball, about 1.5 cm apart."""
    rng = np.random.default_rng(1)
    n_trunk, n_crown = 6000, 4000
    phi = rng.uniform(0, 2 * np.pi, n_trunk)
    trunk = np.c_[0.2 * np.cos(phi), 0.2 * np.sin(phi), rng.uniform(0, 6, n_trunk)]
    v = rng.normal(size=(n_crown, 3))
    crown = 1.5 * v / np.linalg.norm(v, axis=1, keepdims=True) * rng.uniform(
        0.3, 1.0, (n_crown, 1)
    ) ** (1 / 3) + [0, 0, 6.5]
    xyz = np.vstack([trunk, crown]) + np.array([100.0, 200.0, 50.0])
    intensity = rng.integers(0, 65535, len(xyz)).astype(np.uint16)
    return Cloud(xyz, attributes={"intensity": intensity}, name="synthetic")


def _tree_in_target(pair, tree: Cloud, index: np.ndarray) -> np.ndarray:
    return apply_transform(invert_transform(pair.T_tree_target), tree.xyz[index])


def test_truth_is_exact_without_noise(tree: Cloud) -> None:
    pair = simulate_pair(tree, seed=3, noise_m=0.0, separation_deg=60, distance_m=6.0)
    assert len(pair.source) > 100
    assert len(pair.target) > 100
    mapped = apply_transform(pair.T_target_source, pair.source.xyz)
    expected = _tree_in_target(pair, tree, pair.index_source)
    assert np.abs(mapped - expected).max() < 1e-6
    # The target itself is the tree seen from the target scanner.
    expected_t = _tree_in_target(pair, tree, pair.index_target)
    assert np.abs(pair.target.xyz - expected_t).max() < 1e-6


def test_noise_is_along_the_beam(tree: Cloud) -> None:
    noise = 0.004
    pair = simulate_pair(tree, seed=4, noise_m=noise, distance_m=(5.0, 7.0))
    # In the source scanner frame the error of each point is radial with sigma = noise.
    exact = apply_transform(
        invert_transform(pair.T_tree_source), tree.xyz[pair.index_source]
    )
    err = pair.source.xyz - exact
    unit = exact / np.linalg.norm(exact, axis=1, keepdims=True)
    radial = np.einsum("ij,ij->i", err, unit)
    lateral = err - radial[:, None] * unit
    assert np.abs(lateral).max() < 1e-9
    assert 0.8 * noise < radial.std() < 1.2 * noise
    assert abs(radial.mean()) < 0.5 * noise
    # Mapped by the truth, the source lands on the tree within the noise.
    mapped = apply_transform(pair.T_target_source, pair.source.xyz)
    expected = _tree_in_target(pair, tree, pair.index_source)
    assert np.linalg.norm(mapped - expected, axis=1).max() < 6 * noise


def test_wall_hides_what_is_behind_it() -> None:
    g = np.arange(-1.0, 1.0, 0.01)
    yy, zz = np.meshgrid(g, g)
    wall = np.c_[np.full(yy.size, 5.0), yy.ravel(), zz.ravel()]
    behind = np.array([[10.0, 0.0, 0.0], [10.0, 0.3, -0.2]])
    beside = np.array([[10.0, 3.0, 0.0]])
    xyz = np.vstack([wall, behind, beside])
    scan, index = simulate_scan(
        Cloud(xyz),
        np.eye(4),
        res_deg=0.04,
        noise_m=0.0,
        footprint_m=0.01,
        rng=np.random.default_rng(0),
    )
    n_wall = len(wall)
    assert n_wall not in index
    assert n_wall + 1 not in index
    assert n_wall + 2 in index
    assert np.mean(index < n_wall) > 0.95  # the wall itself is seen (nearly) whole
    assert len(scan) == len(index)


def test_visibility_does_not_depend_on_how_points_are_chunked(monkeypatch) -> None:
    from amrst.simulate import scanner

    rng = np.random.default_rng(3)
    # Points on spheres around the scanner, some sharing a range to 0.1 mm: ties.
    d = rng.normal(size=(4000, 3))
    d /= np.linalg.norm(d, axis=1)[:, None]
    xyz = d * rng.choice([2.0, 2.0, 3.5, 7.0], size=4000)[:, None]
    radius = rng.uniform(0.005, 0.05, 4000)
    whole = scanner.visible_points(xyz, 0.2, radius)
    monkeypatch.setattr(scanner, "_CHUNK_CELLS", 997)  # many chunks, odd sizes
    chunked = scanner.visible_points(xyz, 0.2, radius)
    np.testing.assert_array_equal(chunked, whole)
    assert 0 < len(whole) < len(xyz)  # some points hide others


def test_back_of_trunk_is_in_shadow(tree: Cloud) -> None:
    pair = simulate_pair(tree, seed=5, noise_m=0.0, distance_m=8.0)
    spec = pair.spec_target
    az = np.radians(spec["azimuth_deg"])
    towards = np.array([np.cos(az), np.sin(az)])
    trunk = pair.index_target[pair.index_target < 6000]
    rel = tree.xyz[trunk, :2] - trunk_base(tree.xyz)[:2]
    facing = rel @ towards
    # Nearly every trunk point the target sees is on the side facing its scanner.
    assert np.mean(facing > -0.05) > 0.95


def test_scanner_frames_and_specs(tree: Cloud) -> None:
    pair = simulate_pair(tree, seed=6, separation_deg=100, distance_m=(6.0, 9.0))
    base = trunk_base(tree.xyz)
    for pose, spec, dist in (
        (pair.T_tree_target, pair.spec_target, 6.0),
        (pair.T_tree_source, pair.spec_source, 9.0),
    ):
        offset = pose[:3, 3] - base
        assert np.hypot(offset[0], offset[1]) == pytest.approx(dist)
        assert offset[2] == pytest.approx(1.5)
        assert spec["distance_m"] == dist
        assert 0.0 <= spec["tilt_deg"] <= 0.5
        # The scanner z axis is tilted by exactly tilt_deg from the vertical.
        tilt = np.degrees(np.arccos(np.clip(pose[2, 2], -1, 1)))
        assert tilt == pytest.approx(spec["tilt_deg"], abs=1e-9)
    sep = (pair.spec_source["azimuth_deg"] - pair.spec_target["azimuth_deg"]) % 360
    assert sep == pytest.approx(100.0)
    assert rotation_angle_deg(pair.T_target_source[:3, :3]) > 1.0
    assert pair.target.offset.tolist() == [0.0, 0.0, 0.0]
    kept = tree.intensity[pair.index_source]
    np.testing.assert_array_equal(pair.source.intensity, kept)


def test_seed_makes_it_repeatable(tree: Cloud) -> None:
    a = simulate_pair(tree, seed=9)
    b = simulate_pair(tree, seed=9)
    c = simulate_pair(tree, seed=10)
    np.testing.assert_array_equal(a.source.xyz, b.source.xyz)
    np.testing.assert_array_equal(a.T_target_source, b.T_target_source)
    assert not np.allclose(a.T_target_source, c.T_target_source)


def test_write_case_round_trip(tree: Cloud, tmp_path) -> None:
    pair = simulate_pair(tree, seed=2)
    out = write_case(pair, tmp_path / "case", "synthetic.ply", seed=2)
    truth = json.loads((out / "truth.json").read_text())
    assert set(truth) >= CASE_KEYS
    case = read_case(out)
    np.testing.assert_allclose(case.T_target_source, pair.T_target_source)
    assert len(case.source) == truth["n_source"] == len(pair.source)
    # float32 storage keeps the scans to well under a millimetre.
    assert np.abs(case.source.xyz - pair.source.xyz).max() < 1e-4


def test_cli_writes_a_case(tree: Cloud, tmp_path) -> None:
    from amrst import io

    tree_path = tmp_path / "tree.ply"
    io.write(tree_path, tree)
    parser = argparse.ArgumentParser()
    configure_parser(parser)
    args = parser.parse_args(
        [
            str(tree_path),
            "--out",
            str(tmp_path / "c"),
            "--seed",
            "4",
            "--distance-m",
            "6",
            "8",
            "--separation-deg",
            "120",
        ]
    )
    assert run_cli(args) == 0
    truth = json.loads((tmp_path / "c" / "truth.json").read_text())
    assert truth["seed"] == 4
    assert truth["spec_source"]["distance_m"] == 8.0
    bad = parser.parse_args([str(tmp_path / "missing.ply"), "--out", str(tmp_path)])
    assert run_cli(bad) == 2


def test_rejects_tiny_tree() -> None:
    from amrst.errors import InvalidInput

    with pytest.raises(InvalidInput):
        simulate_pair(Cloud(np.zeros((10, 3))))


def test_existing_file_as_out_is_refused(tree: Cloud, tmp_path, capsys) -> None:
    from amrst import io
    from amrst.errors import InvalidInput

    a_file = tmp_path / "taken"
    a_file.write_text("x")
    pair = simulate_pair(tree, seed=2)
    with pytest.raises(InvalidInput, match="existing file"):
        write_case(pair, a_file, "synthetic.ply")
    tree_path = tmp_path / "tree.ply"
    io.write(tree_path, tree)
    parser = argparse.ArgumentParser()
    configure_parser(parser)
    assert run_cli(parser.parse_args([str(tree_path), "--out", str(a_file)])) == 2
    err = capsys.readouterr().err
    assert "existing file" in err
    assert "Traceback" not in err


def test_a_case_is_never_written_over(tree: Cloud, tmp_path, capsys) -> None:
    from amrst import io
    from amrst.errors import InvalidInput

    parser = argparse.ArgumentParser()
    configure_parser(parser)
    tree_path = tmp_path / "tree.ply"
    io.write(tree_path, tree)
    out = tmp_path / "case"
    argv = [str(tree_path), "--out", str(out), "--res-deg", "0.2"]
    assert run_cli(parser.parse_args(argv)) == 0
    before = {p.name: p.read_bytes() for p in out.iterdir()}
    # Another seed into the same case, then the case's own scan as the tree.
    for again in (
        [*argv, "--seed", "5"],
        [str(out / "target.ply"), "--out", str(out), "--res-deg", "0.2"],
    ):
        capsys.readouterr()
        assert run_cli(parser.parse_args(again)) == 2
        err = capsys.readouterr().err
        assert "already holds files" in err
        assert err.count("\n") == 1
        assert {p.name: p.read_bytes() for p in out.iterdir()} == before
    with pytest.raises(InvalidInput, match="already holds files"):
        write_case(simulate_pair(tree, seed=5), out, "synthetic.ply")
    assert {p.name: p.read_bytes() for p in out.iterdir()} == before
    # A new or empty folder is written.
    (tmp_path / "empty").mkdir()
    assert write_case(simulate_pair(tree, seed=5), tmp_path / "empty", "t.ply")


@pytest.mark.parametrize(
    ("option", "value"),
    [
        ("--seed", "-1"),
        ("--separation-deg", "nan"),
        ("--separation-deg", "inf"),
        ("--distance-m", "nan"),
        ("--res-deg", "inf"),
        ("--noise-m", "nan"),
        ("--tilt-deg", "-inf"),
    ],
)
def test_bad_numbers_are_refused_by_option(tmp_path, capsys, option, value) -> None:
    parser = argparse.ArgumentParser()
    configure_parser(parser)
    out = tmp_path / "c"
    args = parser.parse_args(["missing.ply", "--out", str(out), f"{option}={value}"])
    assert run_cli(args) == 2  # refused before reading the (missing) tree
    err = capsys.readouterr().err
    assert option in err
    assert "missing.ply" not in err
    assert not out.exists()


def test_bad_numbers_are_refused_by_the_library(tree: Cloud) -> None:
    from amrst.errors import InvalidInput

    with pytest.raises(InvalidInput, match="seed"):
        simulate_pair(tree, seed=-1)
    with pytest.raises(InvalidInput, match="separation_deg"):
        simulate_pair(tree, separation_deg=float("nan"))
    with pytest.raises(InvalidInput, match="distance_m"):
        simulate_pair(tree, distance_m=(5.0, float("inf")))


def test_tree_giving_too_few_scan_points_is_refused() -> None:
    from amrst.errors import InvalidInput

    # 5000 copies of one point: each scan would keep a single point.
    with pytest.raises(InvalidInput, match=r"keeps only 1 point\(s\).*1 distinct"):
        simulate_pair(Cloud(np.tile([[1.0, 2.0, 3.0]], (5000, 1)), name="same.xyz"))


LENGTH = "must be a number more than 0 and at most 1000 m"


@pytest.mark.parametrize(
    ("command", "options", "expected"),
    [
        ("campaign", ["--res-deg", "nan"], "--res-deg must be a number more than 0"),
        ("plot", ["--range-m", "1e308", "--res-deg", "0.15"], f"--range-m {LENGTH}"),
        ("campaign", ["--noise-m", "-1"], "--noise-m must be a number from 0 to 0.5"),
        ("pair", ["--noise-m", "-1"], "--noise-m must be a number from 0 to 0.5"),
        ("campaign", ["--distance-m", "nan"], f"--distance-m {LENGTH}, got nan."),
        ("pair", ["--distance-m", "1e308"], f"--distance-m {LENGTH}, got 1e+308."),
        ("pair", ["--clip-radius-m", "nan"], f"--clip-radius-m {LENGTH}, got nan."),
        ("pair", ["--separation-deg", "1e308"], "from -360 to 360 degrees"),
        ("pair", ["--res-deg", "1e308"], "--res-deg must be a number more than 0"),
        ("pair", ["--slope-deg", "inf"], "--slope-deg must be a number at least 0"),
        ("pair", ["--shrubs", "-1"], "--shrubs must be an integer from 0 to 1000"),
        ("plot", ["--positions", "1000"], "--positions must be an integer from 2"),
        ("plot", ["--spacing-m", "5", "nan"], f"--spacing-m {LENGTH}, got nan."),
        ("plot", ["--spacing-m", "8", "5"], "--spacing-m must be a range LOW HIGH"),
        ("plot", ["--trees", "2"], "--trees must be an integer of 3 or more"),
        ("campaign", ["--scans", "1"], "--scans must be an integer from 2 to 50"),
        ("campaign", ["--seed", "-1"], "--seed must be an integer of 0 or more"),
        ("campaign", ["--separation-deg", "0", "90"], "more than 0 and at most 360"),
        ("campaign", ["--separation-deg", "90", "60"], "with LOW <= HIGH"),
    ],
)
def test_both_simulate_commands_check_every_number_first(
    tmp_path, capsys, command, options, expected
) -> None:
    from amrst.cli import main

    missing = str(tmp_path / "missing.ply")
    argv = {
        "pair": ["simulate", missing],
        "plot": ["simulate", "--plot", missing, missing, missing],
        "campaign": ["campaign", "simulate", missing],
    }[command]
    out = tmp_path / "case"
    assert main([*argv, "--out", str(out), *options]) == 2
    err = capsys.readouterr().err
    assert expected in err
    assert err.count("\n") == 1
    assert "missing.ply" not in err  # refused before the tree is read
    assert not out.exists()


def test_the_library_checks_the_same_ranges(tree: Cloud) -> None:
    from amrst.errors import InvalidInput
    from amrst.multiscan.simulate import simulate_scans
    from amrst.simulate.field import FieldOptions
    from amrst.simulate.plot import plot_options

    with pytest.raises(InvalidInput, match="noise_m must be a number from 0"):
        simulate_scans(tree, 3, noise_m=-1.0)
    with pytest.raises(InvalidInput, match=r"res_deg must be .*, got nan"):
        simulate_scans(tree, 3, res_deg=float("nan"))
    with pytest.raises(InvalidInput, match=f"distance_m {LENGTH}"):
        simulate_pair(tree, distance_m=1e308)
    with pytest.raises(InvalidInput, match=f"range_m {LENGTH}"):
        plot_options(range_m=1e308)
    with pytest.raises(InvalidInput, match=f"clip_radius_m {LENGTH}"):
        FieldOptions(clip_radius_m=float("nan"))


@pytest.mark.parametrize("name", ["noise_m", "tilt_deg", "seed", "res_deg"])
def test_a_setting_given_as_none_is_refused_in_one_line(tree, name):
    from amrst.errors import InvalidInput

    with pytest.raises(InvalidInput, match=f"{name} must be") as info:
        simulate_pair(tree, **{name: None})
    assert "\n" not in str(info.value)
