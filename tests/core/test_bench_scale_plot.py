"""``amrst bench-scale`` on a plot case: every scan densified, ``amrst plot`` timed."""

from __future__ import annotations

import json
from typing import TYPE_CHECKING

import numpy as np
import pytest
from _plots import STEMS, ground_z, pose, scan

from amrst.bench.densify import dense_name
from amrst.bench.plot import is_plot_case, read_plot_case
from amrst.bench.scale_plot import PLOT_STAGES, make_scale_plot, plot_stages
from amrst.cli import main
from amrst.types import Cloud, invert_transform

if TYPE_CHECKING:
    from pathlib import Path

POSITIONS = ((-2.0, 0.0), (3.0, 1.0), (0.0, -4.5))
POSES = (np.eye(4), pose(70.0, (3.0, 1.0, 0.0), 1.0), pose(-40.0, (0.0, -4.5, 0.0)))


def _thin_ground(xyz: np.ndarray) -> np.ndarray:
    """Every eighth ground point: the plot registers the same, in less time."""
    ground = xyz[:, 2] < ground_z(xyz[:, :2]) + 0.01
    return xyz[~ground | (np.arange(len(xyz)) % 8 == 0)]


def _plot_case(folder: Path, names: tuple[str, ...]) -> list[int]:
    """Write a plot case of ``names`` (.ply) and truth.json; return the scans' sizes."""
    from amrst import io

    folder.mkdir(parents=True)
    sizes = []
    for k, (name, xy, T) in enumerate(zip(names, POSITIONS, POSES, strict=False)):
        inv = invert_transform(T)
        xyz = _thin_ground(scan(xy, STEMS, k)) @ inv[:3, :3].T + inv[:3, 3]
        io.write(folder / f"{name}.ply", Cloud(xyz))
        sizes.append(len(xyz))
    stems = [
        {
            "x": x,
            "y": y,
            "z_base": float(ground_z(np.array([x, y]))),
            "dbh_m": 2 * r,
            "height_m": h,
        }
        for x, y, r, h in STEMS
    ]
    poses = [T.tolist() for T in POSES[: len(names)]]
    doc = {"T_scan1_scank": poses, "stems_target_frame": stems}
    (folder / "truth.json").write_text(json.dumps(doc))
    return sizes


def test_make_scale_plot_densifies_every_scan_under_its_truth(tmp_path: Path) -> None:
    sizes = _plot_case(tmp_path / "plot", ("scan_1", "scan_2", "scan_3"))
    n = 2 * max(sizes)
    dense = make_scale_plot(tmp_path / "plot", tmp_path / "dense", n, seed=3)
    assert sorted(p.name for p in dense.iterdir()) == [
        "scan_1.ply",
        "scan_2.ply",
        "scan_3.ply",
        "truth.json",
    ]
    assert is_plot_case(dense)
    case, sparse = read_plot_case(dense), read_plot_case(tmp_path / "plot")
    assert [len(c) for c in case.clouds] == [n, n, n]
    jitters = []
    for k, (c, s) in enumerate(zip(case.clouds, sparse.clouds, strict=True)):
        jitter = c.xyz - s.xyz[np.arange(n) % len(s)]
        assert jitter.std() == pytest.approx(0.003, rel=0.1)
        jitters.append(jitter[: min(sizes)])
        np.testing.assert_allclose(case.T_scan1_scank[k], sparse.T_scan1_scank[k])
    # Each scan has its own seed: no two scans share their jitter.
    assert not np.allclose(jitters[0], jitters[1])
    truth = json.loads((dense / "truth.json").read_text())
    assert (truth["densify_points"], truth["densify_seed"]) == (n, 3)
    np.testing.assert_array_equal(case.stems, sparse.stems)


def test_plot_stages_are_dated_by_the_progress_and_closing_lines() -> None:
    timings = {"read": 1.0, "analyse": 4.0, "links": 6.0, "joint": 2.0, "total": 13.0}
    lines = [
        (3.1, "WARNING: Large scan: thinned"),
        (3.5, "  0.50s scan 1: preprocess"),
        (9.0, "  6.00s link 1-2: scale 1/3"),
        (20.0, "/out: 6 trees; 2 of 2 scans registered, bundle error 0.2 cm"),
    ]
    stages = plot_stages(timings, lines)
    assert stages == pytest.approx(
        {
            "start": 3.0,
            "read": 1.0,
            "analyse": 4.0,
            "links": 6.0,
            "joint": 2.0,
            "inventory": 4.0,
        }
    )
    # --quiet writes no progress: only the reading and registration are dated.
    assert set(plot_stages(timings, [])) == {"read", "analyse", "links", "joint"}


@pytest.mark.slow
def test_bench_scale_times_amrst_plot_on_a_dense_plot(tmp_path: Path) -> None:
    """The command sees a plot case by its truth, densifies its two scans and runs
    amrst plot on them in a child process: the scan placed, every tree found."""
    sizes = _plot_case(tmp_path / "plot", ("target", "source"))
    n = max(sizes) + 1000
    out = tmp_path / "out"
    args = [
        "bench-scale",
        str(tmp_path / "plot"),
        "--points",
        str(n),
        "--out",
        str(out),
    ]
    assert main(args) == 0
    dense = out / dense_name("plot", n, 0.003, 0)
    assert [len(c) for c in read_plot_case(dense).clouds] == [n, n]
    text = (out / "scale.md").read_text()
    row = next(ln for ln in text.splitlines() if ln.startswith(f"| {dense.name} |"))
    cells = [c.strip() for c in row.strip("|").split("|")]
    assert cells[1] == f"2 x {n:,}"
    stages = [float(c) for c in cells[2 : 2 + len(PLOT_STAGES)]]
    rest = cells[2 + len(PLOT_STAGES) :]
    wall, peak = float(rest[0]), float(rest[1].replace(",", ""))
    assert all(s >= 0 for s in stages)
    assert 0 < sum(stages) <= wall + 0.1  # the rounding of seven cells
    assert peak > 50
    assert (rest[2], rest[4], rest[5]) == ("1/1", "6/6", "0")
    worst_deg, worst_cm = (float(v) for v in rest[3].split(" / "))
    assert worst_deg < 1
    assert worst_cm < 5
    assert "scans registered" in text  # the command's own closing line, kept
