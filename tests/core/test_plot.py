"""amrst.plot: the stem map, stem registration of a plot pair, and the inventory.

The plots are built here: a gently sloped ground and upright stems (cylinders), each
scan seeing the half of every stem that faces its position, in its own frame.
"""

from __future__ import annotations

import csv
from typing import TYPE_CHECKING

import numpy as np
import pytest
from _plots import STEMS, ground_z, pose, scan

from amrst.plot.cli import main as plot_main
from amrst.plot.export import TREES_CSV, trees_csv
from amrst.plot.inventory import take_inventory
from amrst.plot.register import analyse_plot_scan, plot_params, register_plot_link
from amrst.plot.stemmap import StemMapParams, map_stems
from amrst.types import Cloud, invert_transform, rotation_angle_deg

if TYPE_CHECKING:
    from pathlib import Path


@pytest.fixture(scope="module")
def plot_pair() -> tuple[Cloud, Cloud, np.ndarray]:
    """Target and source scans of one plot, and the true T_target_source."""
    target = scan((-2.0, 0.0), STEMS, 1, hidden_tops=True)
    T_plot_source = pose(70.0, (3.0, 1.0, 0.0), tilt_deg=1.0)
    world = scan((3.0, 1.0), STEMS, 2, hidden_tops=True)
    source = (
        world @ invert_transform(T_plot_source)[:3, :3].T
        + (invert_transform(T_plot_source)[:3, 3])
    )
    return Cloud(target, name="t"), Cloud(source, name="s"), T_plot_source


def test_stem_map_finds_every_stem_with_its_dbh() -> None:
    m = map_stems(scan((0.5, 0.5), STEMS, 3))
    assert len(m.stems) == len(STEMS)
    for x, y, r, h in STEMS:
        d = [np.hypot(*(s.base[:2] - (x, y))) for s in m.stems]
        s = m.stems[int(np.argmin(d))]
        assert min(d) < 0.1
        assert abs(s.dbh_m - 2 * r) < 0.01
        assert abs(s.height_m - h) < 0.3
        assert s.lean_deg < 3.0


def test_stems_register_a_tilted_plot_pair(plot_pair) -> None:
    target, source, T_true = plot_pair
    params = plot_params()
    scans = [analyse_plot_scan(c, params, StemMapParams()) for c in (target, source)]
    link = register_plot_link(scans[0], scans[1], (0, 1), params).link
    assert link.verdict == "verified"
    assert link.origin == "stems"
    E = invert_transform(T_true) @ link.T_local
    assert rotation_angle_deg(E[:3, :3]) < 1.0
    assert np.linalg.norm(E[:3, 3]) < 0.05


def test_a_tree_seen_from_two_scans_is_listed_once(plot_pair) -> None:
    target, source, T_true = plot_pair
    inv = take_inventory([target, source], [np.eye(4), T_true])
    assert len(inv.trees) == len(STEMS)
    assert all(t.seen_from == (1, 2) for t in inv.trees)
    dbh = sorted(t.stem.dbh_m for t in inv.trees)
    assert np.allclose(dbh, sorted(2 * s[2] for s in STEMS), atol=0.01)
    # Ids follow the positions: the same files give the same ids.
    again = take_inventory([target, source], [np.eye(4), T_true])
    assert [t.row() for t in again.trees] == [t.row() for t in inv.trees]


def test_two_stems_0_6_m_apart_are_two_trees() -> None:
    stems = ((0.0, 0.0, 0.12, 6.0), (0.6, 0.0, 0.12, 6.0), (3.0, 3.0, 0.15, 6.0))
    inv = take_inventory([Cloud(scan((0.3, -4.0), stems, 4))], [np.eye(4)])
    xs = sorted(round(float(t.xyz[0]), 1) for t in inv.trees if abs(t.xyz[1]) < 0.3)
    assert xs == [0.0, 0.6]


def test_inventory_columns_and_the_command(plot_pair, tmp_path: Path) -> None:
    from amrst import io

    target, source, _ = plot_pair
    header = trees_csv(take_inventory([target], [np.eye(4)])).splitlines()[0]
    need = "tree_id,x_m,y_m,z_m,height_m,dbh_m,dbh_quality,crown_width_m,n_points"
    assert set(need.split(",")) | {"seen_from"} <= set(header.split(","))
    files = [tmp_path / "t.ply", tmp_path / "s.ply"]
    for f, c in zip(files, (target, source), strict=True):
        io.write(f, c)
    out = tmp_path / "out"
    args = [str(f) for f in files] + ["--out", str(out), "--quiet"]
    assert plot_main(args) == 0
    with (out / TREES_CSV).open() as fh:
        rows = list(csv.DictReader(fh))
    assert len(rows) == len(STEMS)
    assert plot_main(args) == 2  # another run's output is not replaced
    assert plot_main([*args, "--overwrite"]) == 0
    assert plot_main([str(tmp_path / "missing.ply"), *args[1:]]) == 2


def test_a_stem_inside_a_wide_thicket_is_found() -> None:
    stems = ((0.0, 0.0, 0.14, 6.0), (4.0, 3.0, 0.12, 6.0))
    xyz = scan((0.0, -5.0), stems, 5)
    rng = np.random.default_rng(6)
    # Leaves and twigs 0.3-1.6 m high over 3 m around the first stem: one slice
    # cluster far wider than a stem.
    leaves = rng.uniform((-1.5, -1.5, 0.3), (1.5, 1.5, 1.6), (20_000, 3))
    leaves = leaves[np.hypot(leaves[:, 0], leaves[:, 1]) > 0.17]
    leaves[:, 2] += ground_z(leaves[:, :2])
    m = map_stems(np.vstack([xyz, leaves]))
    bases = np.array([s.base[:2] for s in m.stems])
    assert len(m.stems) == 2
    assert np.hypot(*bases[np.argmin(np.hypot(*bases.T))]) < 0.1


def test_a_top_cut_by_the_scanner_range_is_flagged() -> None:
    stems = ((4.0, 0.0, 0.15, 14.0), (-3.0, 2.0, 0.12, 5.0), (0.0, -4.0, 0.1, 4.0))
    xyz = scan((0.0, 0.0), stems, 7)
    xyz = xyz[np.linalg.norm(xyz, axis=1) <= 10.0]  # the scanner's range
    inv = take_inventory([Cloud(xyz)], [np.eye(4)])
    flags = {round(float(t.xyz[0])): t.stem.height_flag for t in inv.trees}
    assert flags == {4: "top not seen", -3: "ok", 0: "ok"}
