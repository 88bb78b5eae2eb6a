"""Forest plots for the virtual scanner: files, exact poses, stem truth, seeds, bad input.

The trees are small synthetic ones (an upright stem of known radius and a crown), the
plot and the scan range small and the beams coarse, so each plot takes about a second.
"""

from __future__ import annotations

import argparse
import json
from dataclasses import replace
from typing import TYPE_CHECKING

import numpy as np
import pytest

from amrst.errors import InvalidInput
from amrst.simulate.cli import configure_parser, run_cli
from amrst.simulate.plot import (
    plot_options,
    plot_scene,
    plot_truth,
    simulate_plot,
    write_plot_case,
)
from amrst.types import Cloud, apply_transform

if TYPE_CHECKING:
    from pathlib import Path

STEM_RADIUS_M = 0.12
# The truth keys of the shared plot cases (amrst bench reads them).
TRUTH_KEYS = {
    "T_scan1_scank",
    "spec_target",
    "spec_source",
    "trees",
    "stems_xy",
    "stems_target_frame",
    "kind",
    "seed",
    "n_points",
    "what",
}
SMALL = {
    "res_deg": 0.25,
    "range_m": 9.0,
    "plot_radius_m": 5.0,
    "spacing_m": (3.0, 5.0),
    "ground_spacing_m": 0.2,
    "shrubs": 3,
}


def _tree(seed: int) -> Cloud:
    """A 4 m stem of radius 0.12 m (points every 2 cm) under a leafy crown."""
    rng = np.random.default_rng(seed)
    a, z = np.meshgrid(
        np.linspace(0, 2 * np.pi, 38, endpoint=False), np.arange(0, 4, 0.02)
    )
    stem = np.column_stack(
        [
            STEM_RADIUS_M * np.cos(a.ravel()),
            STEM_RADIUS_M * np.sin(a.ravel()),
            z.ravel(),
        ]
    )
    crown = rng.normal(0.0, 1.0, (3000, 3)) * [1.0, 1.0, 0.8] + [0.0, 0.0, 4.5]
    return Cloud(
        np.vstack([stem, crown]) + np.array([5.0, -3.0, 100.0]),
        name=f"t/tree_{seed}.ply",
    )


@pytest.fixture(scope="module")
def trees() -> list[Cloud]:
    return [_tree(k) for k in range(4)]


@pytest.fixture(scope="module")
def plot3(trees):
    """Three positions, no range noise: kept points are scene points exactly."""
    return simulate_plot(
        trees, plot_options("normal", positions=3, noise_m=0.0, **SMALL), seed=7
    )


def test_trees_stand_apart_in_the_plot_and_the_tripods_clear_of_them(trees) -> None:
    options = plot_options("hard", positions=3, **{**SMALL, "spacing_m": (4.0, 6.0)})
    scene = plot_scene(trees, options, seed=3)
    feet = np.array([t.foot[:2] for t in scene.trees])
    assert len(feet) == 4
    gaps = np.hypot(*(feet[:, None] - feet[None]).T)[np.triu_indices(4, 1)]
    assert gaps.min() >= 3.0
    assert np.hypot(*feet.T).max() <= 5.0
    steps = np.hypot(*np.diff(scene.positions[:, :2], axis=0).T)
    assert np.all((steps >= 4.0) & (steps <= 6.0))
    assert np.hypot(*(scene.positions[:, None, :2] - feet[None]).T).min() >= 1.5
    # Every tree point is labelled with its tree; each tree stands on the ground.
    for k, tree in enumerate(scene.trees):
        own = scene.cloud.xyz[scene.tree_of == k]
        assert len(own) == len(trees[0])
        assert tree.height_m == pytest.approx(own[:, 2].max() - tree.foot[2])


def test_truth_poses_map_every_scan_onto_scan_1(plot3) -> None:
    from scipy.spatial import cKDTree

    first = plot3.scans[0].xyz
    tree1 = cKDTree(first)
    poses = plot3.T_scan1_scank()
    np.testing.assert_allclose(poses[0], np.eye(4), atol=1e-12)
    for k in (1, 2):
        moved = apply_transform(poses[k], plot3.scans[k].xyz)
        # Points of scan k on the stems that scan 1 also saw land on scan 1's points.
        d = tree1.query(moved, distance_upper_bound=0.5)[0]
        assert np.median(d[np.isfinite(d)]) < 0.02
        shifted = tree1.query(
            moved + np.array([0.2, 0.0, 0.0]), distance_upper_bound=0.5
        )[0]
        assert np.median(shifted[np.isfinite(shifted)]) > 0.05


def test_stem_truth_sits_on_the_scanned_stems(plot3) -> None:
    truth = plot_truth(plot3, seed=7)
    scan = plot3.scans[0].xyz
    for stem in truth["stems_target_frame"]:
        # The scaled stem's diameter, from the complete tree.
        assert 0.85 * 0.24 - 0.01 <= stem["dbh_m"] <= 1.15 * 0.24 + 0.01
        assert stem["height_m"] > 4.0
        near = np.hypot(scan[:, 0] - stem["x"], scan[:, 1] - stem["y"]) < 0.5
        ring = scan[near & (np.abs(scan[:, 2] - stem["z_base"] - 1.3) < 0.1)]
        if len(ring) < 10:
            continue  # hidden from scan 1
        # Bark points lie one stem radius from the truth's axis.
        r = np.hypot(ring[:, 0] - stem["x"], ring[:, 1] - stem["y"])
        assert np.median(r) == pytest.approx(stem["dbh_m"] / 2, abs=0.03)


def test_case_files_and_truth_read_back(plot3, trees, tmp_path: Path) -> None:
    from amrst.bench.plot import is_plot_case, read_plot_case

    out = write_plot_case(plot3, tmp_path / "p3", seed=7)
    assert sorted(p.name for p in out.iterdir()) == [
        "scan_1.ply",
        "scan_2.ply",
        "scan_3.ply",
        "truth.json",
    ]
    truth = json.loads((out / "truth.json").read_text())
    assert set(truth) >= TRUTH_KEYS
    assert "T_target_source" not in truth
    assert truth["n_points"] == [len(s) for s in plot3.scans]
    assert is_plot_case(out)
    case = read_plot_case(out)
    assert len(case.clouds) == 3
    assert case.stems.shape == (4, 5)
    np.testing.assert_allclose(case.T_scan1_scank[2], plot3.T_scan1_scank()[2])
    assert np.abs(case.clouds[1].xyz - plot3.scans[1].xyz).max() < 1e-4
    # Two positions: target + source, and T_target_source.
    pair = simulate_plot(trees[:3], plot_options("sparse", **SMALL), seed=2)
    out2 = write_plot_case(pair, tmp_path / "p2", seed=2)
    names = {p.name for p in out2.iterdir()}
    assert names == {"target.ply", "source.ply", "truth.json"}
    truth2 = json.loads((out2 / "truth.json").read_text())
    assert truth2["T_target_source"] == truth2["T_scan1_scank"][1]
    assert truth2["spec_source"]["res_deg"] == 2 * truth2["spec_target"]["res_deg"]
    assert truth2["kind"] == "sparse"
    # A plot case is never written over.
    with pytest.raises(InvalidInput, match="already holds files"):
        write_plot_case(pair, out2, seed=2)


def test_same_seed_same_plot_and_progress_scan_by_scan(trees) -> None:
    from amrst.progress import EventReporter

    seen: list[tuple[float, str]] = []
    options = plot_options("normal", **SMALL)
    a = simulate_plot(
        trees, options, seed=5, reporter=EventReporter(lambda f, m: seen.append((f, m)))
    )
    fractions = [f for f, _ in seen]
    assert fractions == sorted(fractions)
    assert fractions[-1] == 1.0
    assert {m for _, m in seen} >= {"scan 1 of 2", "scan 2 of 2"}
    b = simulate_plot(trees, options, seed=5)
    for sa, sb in zip(a.scans, b.scans, strict=True):
        np.testing.assert_array_equal(sa.xyz, sb.xyz)
    assert json.dumps(plot_truth(a, 5)) == json.dumps(plot_truth(b, 5))
    other = plot_scene(trees, options, seed=6)
    assert not np.allclose(
        plot_scene(trees, options, seed=5).positions, other.positions
    )


def test_relief_bends_the_ground_and_keeps_the_rest_of_the_plot(trees) -> None:
    options = plot_options("normal", noise_m=0.0, **SMALL)
    flat = plot_scene(trees, options, seed=5)
    hilly = plot_scene(trees, replace(options, relief_m=1.0), seed=5)
    assert np.array_equal(flat.positions[:, :2], hilly.positions[:, :2])
    for a, b in zip(flat.trees, hilly.trees, strict=True):
        assert a.name == b.name
        assert np.array_equal(a.foot[:2], b.foot[:2])
    ground = hilly.tree_of < 0  # ground and shrubs, as the flat plot's
    xyz = hilly.cloud.xyz[ground & (np.abs(hilly.cloud.xyz[:, 2]) < 50)]
    A = np.c_[xyz[:, :2], np.ones(len(xyz))]
    off = xyz[:, 2] - A @ np.linalg.lstsq(A, xyz[:, 2], rcond=None)[0]
    assert np.percentile(np.abs(off), 95) > 0.3  # no plane holds it
    feet = np.array([t.foot for t in hilly.trees])
    assert not np.allclose(feet[:, 2], [t.foot[2] for t in flat.trees])


def test_wind_sways_the_trees_in_the_later_scans_only(trees) -> None:
    from scipy.spatial import cKDTree

    options = plot_options("wind", noise_m=0.0, **SMALL)
    plot = simulate_plot(trees, options, seed=4)
    scene = plot_scene(trees, options, seed=4)  # the plot's scene, as it stands
    on_scene = cKDTree(scene.cloud.xyz)
    feet_z = np.array([t.foot[2] for t in scene.trees])
    for k, moved in ((0, False), (1, True)):
        xyz = apply_transform(plot.poses[k], plot.scans[k].xyz)
        d, nearest = on_scene.query(xyz)
        tree = scene.tree_of[nearest]
        crown = (tree >= 0) & (xyz[:, 2] - feet_z[tree] > 3.0)
        assert crown.sum() > 20
        assert np.median(d[tree < 0]) < 1e-6  # ground and shrubs stand still
        assert (np.median(d[crown]) > 1e-3) == moved


def test_a_stray_point_of_a_tree_file_is_not_its_top(trees) -> None:
    # A tree file can hold single points metres off its crown; the truth height is
    # the crown's top, not theirs.
    stray = np.array([[20.0, 0.0, 3.0]]) + trees[0].xyz.max(axis=0)
    strayed = [Cloud(np.vstack([trees[0].xyz, stray]), name="t/stray.ply"), *trees[1:]]
    options = plot_options("normal", **SMALL)
    clean, with_stray = (plot_scene(t, options, seed=3) for t in (trees, strayed))
    k = next(i for i, t in enumerate(clean.trees) if t.name == trees[0].name)
    assert with_stray.trees[k].height_m == pytest.approx(clean.trees[k].height_m)


def _cli(argv: list[str], capsys) -> tuple[int, str]:
    parser = argparse.ArgumentParser()
    configure_parser(parser)
    code = run_cli(parser.parse_args(argv))
    return code, capsys.readouterr().err


def test_cli_writes_a_plot_case(trees, tmp_path: Path, capsys) -> None:
    paths = _tree_files(trees, tmp_path)
    out = tmp_path / "case"
    small = ["--res-deg", "0.5", "--range-m", "5", "--shrubs", "2"]
    argv = [*paths, "--plot", "--out", str(out), "--seed", "3", "--trees", "3"]
    code, err = _cli([*argv, *small, "--kind", "hard", "--tilt-deg", "1"], capsys)
    assert code == 0, err
    assert "2 scans" in err
    truth = json.loads((out / "truth.json").read_text())
    assert len(truth["trees"]) == 3
    assert truth["trees"][0].startswith(f"{tmp_path.name}/tree_")
    assert truth["kind"] == "hard"
    assert max(s["tilt_deg"] for s in truth["specs"]) <= 1.0
    assert (out / "source.ply").is_file()
    # Run again into the same folder: refused, the case is kept.
    code, err = _cli([*argv, *small], capsys)
    assert code == 2
    assert "already holds files" in err
    assert (out / "source.ply").is_file()


def _tree_files(trees: list[Cloud], folder: Path) -> list[str]:
    from amrst import io

    paths = []
    for k, tree in enumerate(trees):
        paths.append(str(folder / f"tree_{k}.ply"))
        io.write(paths[-1], tree)
    return paths


@pytest.mark.parametrize(
    ("more_files", "options", "expected"),
    [
        (["missing.ply"], [], "not found"),
        (["bad.ply"], [], "bad.ply"),
        ([], ["--trees", "5"], "needs as many tree clouds"),
        ([], ["--positions", "1"], "--positions must be an integer from 2 to 50"),
        ([], ["--spacing-m", "1", "2", "3"], "--spacing-m takes one"),
        ([], ["--res-deg", "nan"], "--res-deg"),
        ([], ["--seed", "-1"], "--seed"),
        ([], ["--neighbours", "x.ply"], "--neighbours applies to a one-tree case"),
        ([], ["--range-m", "100"], "give a shorter --range-m"),  # out of memory
        ([], ["--range-m", "1e12"], "--range-m must be a number more than 0 and at"),
        ([], ["--relief-m", "50"], "--relief-m must be a number from 0 to 10 m"),
        ([], ["--shrubs", "100000000"], "--shrubs must be an integer from 0 to 1000"),
        (["two_trees.ply"], [], "as a plot of several trees does"),
        (["in_mm.ply"], [], "are its coordinates in millimetres or centimetres?"),
        (["one_point.ply"], [], "one_point.ply has 1 point(s) over 0 m of height"),
        (["flat.ply"], [], "flat.ply has 500 point(s) over 0 m of height"),
    ],
)
def test_cli_bad_plot_input_is_one_line(
    trees, tmp_path: Path, capsys, more_files, options, expected
) -> None:
    from amrst import io

    (tmp_path / "bad.ply").write_bytes(b"ply\nformat nonsense\n")
    apart = np.add(trees[0].xyz, (8.0, 0.0, 0.0))  # a plot subset given as a tree
    io.write(tmp_path / "two_trees.ply", Cloud(np.vstack([trees[0].xyz, apart])))
    io.write(tmp_path / "in_mm.ply", Cloud(np.tile(1000 * trees[0].xyz, (2, 1))))
    io.write(tmp_path / "one_point.ply", Cloud(np.zeros((1, 3))))
    io.write(tmp_path / "flat.ply", Cloud(np.zeros((500, 3))))  # one point, repeated
    files = _tree_files(trees[:3], tmp_path) + [str(tmp_path / f) for f in more_files]
    out = tmp_path / "case"
    code, err = _cli([*files, "--plot", "--out", str(out), *options], capsys)
    assert code == 2
    assert expected in err
    assert err.count("\n") == 1
    assert "Traceback" not in err
    assert not out.exists()


def test_cli_plot_options_need_plot_and_plots_need_three_trees(
    trees, tmp_path: Path, capsys
) -> None:
    path = _tree_files(trees[:1], tmp_path)[0]
    out = str(tmp_path / "case")
    code, err = _cli([path, "--out", out, "--positions", "3"], capsys)
    assert code == 2
    assert "--positions applies to a forest plot" in err
    code, err = _cli([path, path, "--out", out], capsys)
    assert code == 2
    assert "Give one TREE" in err
    code, err = _cli([path, path, "--plot", "--out", out], capsys)
    assert code == 2
    assert "needs as many tree clouds, got 2; give more" in err
    assert err.rstrip().endswith("a plot has 3 at least.")
