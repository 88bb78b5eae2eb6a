"""amrst.plot: the stem map, stem registration of a plot pair, and the inventory.

The plots are built here: a gently sloped ground and upright stems (cylinders), each
scan seeing the half of every stem that faces its position, in its own frame.
"""

from __future__ import annotations

import csv
import dataclasses
import json
import os
import re
from dataclasses import replace
from typing import TYPE_CHECKING

import _plots
import numpy as np
import pytest
from _plots import STEMS, blob, ground_z, pose, scan, wave_z

from amrst.files.folderlock import FolderBusy, FolderLock
from amrst.plot.cli import main as plot_main
from amrst.plot.diameter import taper_dbh
from amrst.plot.export import TREES_CSV, trees_csv, write_inventory
from amrst.plot.flags import height_words
from amrst.plot.inventory import take_inventory
from amrst.plot.match import (
    HELD_HEADING_SD_DEG,
    StemPose,
    _heading_sd_deg,
    held_by_stems,
    key_weights,
    stem_poses,
)
from amrst.plot.register import analyse_plot_scan, plot_params, register_plot_link
from amrst.plot.review import HandCircle, PlotReview, read_review, write_review
from amrst.plot.stemmap import StemMapParams, StemRecord, branch_axis, map_stems
from amrst.types import Cloud, invert_transform, rotation_angle_deg

if TYPE_CHECKING:
    from pathlib import Path


@pytest.fixture(scope="module")
def plot_pair() -> tuple[Cloud, Cloud, np.ndarray]:
    """Target and source scans of one plot, and the true T_target_source."""
    target, source, T_true = _plots.plot_pair()
    return Cloud(target, name="t"), Cloud(source, name="s"), T_true


@pytest.fixture(scope="module")
def plot_scans(plot_pair):
    """The plot pair analysed as amrst plot does: its settings and both scans."""
    params = plot_params()
    scans = [analyse_plot_scan(c, params, StemMapParams()) for c in plot_pair[:2]]
    return params, scans


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


def test_stray_echoes_below_the_ground_hide_no_tree() -> None:
    # Lone points up to 1.6 m below the ground, out to 120 m (2 % of the scan):
    # as cell minima they outnumber the ground's cells, and drew its plane.
    xyz = scan((0.5, 0.5), STEMS, 3)
    rng = np.random.default_rng(9)
    xy = rng.uniform(-120, 120, (len(xyz) // 50, 2))
    strays = np.c_[xy, ground_z(xy) - rng.uniform(0.3, 1.6, len(xy))]
    m = map_stems(np.vstack([xyz, strays]))
    assert abs(m.ground.surface_z(np.zeros((1, 2)))[0] - ground_z(np.zeros(2))) < 0.05
    assert len(m.stems) == len(STEMS)
    for x, y, _r, h in STEMS:
        d = [np.hypot(*(s.base[:2] - (x, y))) for s in m.stems]
        assert min(d) < 0.1
        assert abs(m.stems[int(np.argmin(d))].height_m - h) < 0.3


def test_the_stem_map_follows_a_ground_that_bends() -> None:
    # Waves of 0.6 m across the plot: a plane through them is half a metre off in
    # places, and every height measured from it, the breast-height slice among them.
    m = map_stems(scan((0.5, 0.5), STEMS, 3, ground=wave_z))
    xy = np.mgrid[-11:11.5:0.5, -11:11.5:0.5].reshape(2, -1).T + 0.25  # cell centres
    off = np.abs(m.ground.surface_z(xy) - wave_z(xy))
    assert np.percentile(off, 99) < 0.03
    assert off.max() < 0.2  # the scanner's foot, where no ground is seen
    assert len(m.stems) == len(STEMS)
    for x, y, r, h in STEMS:
        d = [np.hypot(*(s.base[:2] - (x, y))) for s in m.stems]
        s = m.stems[int(np.argmin(d))]
        assert min(d) < 0.1
        assert abs(s.base[2] - wave_z(np.array([x, y]))) < 0.1  # 5 cm into the ground
        assert abs(s.dbh_m - 2 * r) < 0.01
        assert abs(s.height_m - h) < 0.3


def test_a_stem_pose_is_levelled_on_the_ground_both_scans_see() -> None:
    # Each scan sees its own stretch of the waves: their ground planes lean apart by
    # degrees, and a pose that made them meet would be tilted by as much.

    T_true = pose(70.0, (4.0, 0.0, 0.0), tilt_deg=1.0)
    target = scan((-4.0, 0.0), STEMS, 1, hidden_tops=True, ground=wave_z, reach_m=9)
    world = scan((4.0, 0.0), STEMS, 2, hidden_tops=True, ground=wave_z, reach_m=9)
    source = world @ T_true[:3, :3] - T_true[:3, 3] @ T_true[:3, :3]
    maps = [map_stems(c, trees=False) for c in (target, source)]
    leaning = np.degrees(np.arccos(maps[0].ground.normal @ maps[1].ground.normal))
    assert leaning > 2.0  # the planes of the two grounds, as the scans see them
    best = stem_poses(*maps)[0]
    E = invert_transform(T_true) @ best.T_target_source
    assert rotation_angle_deg(E[:3, :3]) < 0.3
    assert np.linalg.norm(E[:3, 3]) < 0.05
    assert best.rms_m < 0.03  # how far its stems meet at this pose, not a tilted one


def test_stems_register_a_tilted_plot_pair(plot_pair, plot_scans) -> None:
    T_true = plot_pair[2]
    params, scans = plot_scans
    link = register_plot_link(scans[0], scans[1], (0, 1), params).link
    assert link.verdict == "verified"
    assert link.origin == "stems"
    E = invert_transform(T_true) @ link.T_local
    assert rotation_angle_deg(E[:3, :3]) < 1.0
    assert np.linalg.norm(E[:3, 3]) < 0.05


def test_stem_poses_are_scored_on_the_trees_at_their_best_pose(plot_pair) -> None:
    from amrst.plot.match import stem_poses
    from amrst.plot.register import (
        SCORE_ABOVE_GROUND_M,
        _above_ground,
        _score_stem_pose,
    )
    from amrst.review.manual import ManualScorer, tight_share

    target, source, T_true = plot_pair
    params = plot_params()
    t, s = (analyse_plot_scan(c, params, StemMapParams()) for c in (target, source))
    above = _above_ground(s, params)
    assert 0 < len(above) < len(s.analysis.xyz)
    assert (s.stems.ground.height(above) > SCORE_ABOVE_GROUND_M).all()
    many = replace(params, coarse=replace(params.coarse, verify_points=len(above) + 1))
    assert len(_above_ground(s, many)) == len(s.analysis.xyz)  # too few: all points

    xyz = s.analysis.xyz
    scorer = ManualScorer(t.analysis.xyz, xyz, params.coarse, score_xyz=above)
    plain = ManualScorer(t.analysis.xyz, xyz, params.coarse)
    assert np.isin(scorer.sample, above).all()  # scored on the trees,
    assert np.array_equal(scorer.src_small, plain.src_small)  # polished on all
    pose = replace(stem_poses(t.stems, s.stems)[0], T_target_source=T_true)
    cand = _score_stem_pose(scorer, pose, 7, "a test", "above the ground ")
    given = tight_share(T_true, scorer.tree, scorer.sample, params.coarse.tight_dist_m)
    assert cand.polished  # every stem pose is every other's rival
    assert cand.score >= given
    if cand.score == given:
        assert np.array_equal(cand.T_target_source, T_true)
        assert cand.explanation.endswith("as given.")
    assert "points above the ground lie within 4 cm" in cand.explanation


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


def test_a_tree_only_one_scan_has_points_on_is_seen_from_that_scan(plot_pair) -> None:
    target, source, T_true = plot_pair
    stem = STEMS[0]
    # The source's points on the first stem are gone, as if a neighbour hid it.
    moved = source.xyz @ T_true[:3, :3].T + T_true[:3, 3]
    off = np.hypot(moved[:, 0] - stem[0], moved[:, 1] - stem[1]) > 1.5
    hidden = Cloud(source.xyz[off], name="s")
    inv = take_inventory([target, hidden], [np.eye(4), T_true])
    seen = {
        (round(float(t.xyz[0])), round(float(t.xyz[1]))): t.seen_from for t in inv.trees
    }
    assert seen.pop((round(stem[0]), round(stem[1]))) == (1,)
    assert set(seen.values()) == {(1, 2)}


def test_two_stems_0_6_m_apart_are_two_trees() -> None:
    stems = ((0.0, 0.0, 0.12, 6.0), (0.6, 0.0, 0.12, 6.0), (3.0, 3.0, 0.15, 6.0))
    inv = take_inventory([Cloud(scan((0.3, -4.0), stems, 4))], [np.eye(4)])
    xs = sorted(round(float(t.xyz[0]), 1) for t in inv.trees if abs(t.xyz[1]) < 0.3)
    assert xs == [0.0, 0.6]


def test_inventory_columns_and_the_command(
    plot_pair, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    from amrst import io

    target, source, T_true = plot_pair
    rows = list(
        csv.DictReader(
            trees_csv(
                take_inventory([target, source], [np.eye(4), T_true]).trees
            ).splitlines()
        )
    )
    assert list(rows[0]) == [
        "tree_id",
        "x_m",
        "y_m",
        "z_m",
        "height_m",
        "height_flag",
        "height_seen_m",
        "dbh_m",
        "dbh_quality",
        "dbh_arc_deg",
        "dbh_rmse_m",
        "dbh_outlier_share",
        "dbh_why",
        "lean_deg",
        "crown_width_m",
        "n_points",
        "seen_from",
        "scans_to_check",
        "mark",
        "dbh_hand_m",
        "in_plot",
    ]
    for row in rows:
        assert row["height_flag"] in {"ok", "lean", "top not seen", "top out of range"}
        assert bool(row["height_m"]) == (row["height_flag"] != "top out of range")
        assert bool(row["height_seen_m"]) == (not row["height_m"])
        assert row["dbh_quality"] in {"ok", "check", "none"}
        assert bool(row["dbh_why"]) == (row["dbh_quality"] != "ok")
        assert 0 < float(row["dbh_m"]) < 0.6
        assert 0 <= float(row["dbh_outlier_share"]) <= 1
        assert 60 <= float(row["dbh_arc_deg"]) <= 360
        assert float(row["lean_deg"]) < 5
        assert int(row["n_points"]) > 0
        assert row["seen_from"] == "1;2"
        assert row["scans_to_check"] == ""  # no scan needs review
        assert row["mark"] == ""
        assert row["in_plot"] == ""  # no plot radius given
    files = _pair_files(plot_pair, tmp_path)
    (tmp_path / "stand7_pos2.ply").symlink_to(files[1])  # a scan under another name
    files[1] = tmp_path / "stand7_pos2.ply"
    out = tmp_path / "out"
    args = [str(f) for f in files] + ["--out", str(out), "--quiet"]
    assert plot_main(args) == 0
    with (out / TREES_CSV).open() as fh:
        rows = list(csv.DictReader(fh))
    assert len(rows) == len(STEMS)
    doc = json.loads((out / "plot.json").read_text())
    assert doc["scans"][1]["label"] == str(files[1])  # the name given, not the target
    assert [s["status"] for s in doc["scans"]] == ["registered", "registered"]
    assert [d["loop_confirmed"] for d in doc["links"]] == [False]  # a pair: no loop
    assert doc["loops"] == []
    assert doc["amrst_version"]
    assert doc["written_utc"].endswith("+00:00")
    _reads_back(out, T_true)
    assert plot_main(args) == 2  # another run's output is not replaced
    # The registered plot: both scans in the reference frame, by scan number.
    assert plot_main([*args, "--overwrite", "--write-cloud"]) == 0
    merged = io.read(out / "plot.laz")
    ids = merged.attributes["scan_id"]
    assert np.bincount(ids).tolist() == [0, len(target), len(source)]
    world = merged.xyz + merged.offset
    moved = source.xyz @ T_true[:3, :3].T + T_true[:3, 3]
    assert np.abs(world[ids == 2] - moved).max() < 0.01
    assert np.abs(world[ids == 1] - target.xyz).max() < 1e-4
    # Each point names its tree by trees.csv's row, from 1; the ground is no tree's.
    tree = merged.attributes["tree"]
    for n, row in enumerate(rows, start=1):
        foot = np.array([float(row[k]) for k in ("x_m", "y_m", "z_m")])
        up = world[:, 2] - foot[2]
        bark = (np.hypot(*(world[:, :2] - foot[:2]).T) < 0.4) & (up > 1.0) & (up < 1.6)
        assert np.mean(tree[bark] == n) > 0.9, row["tree_id"]
    assert np.mean(tree == 0) > 0.1  # the ground
    # What no tree owns on the ground is ground (ASPRS class 2), the rest class 1.
    ground = merged.attributes["classification"] == 2
    assert set(np.unique(merged.attributes["classification"])) == {1, 2}
    assert not ground[tree > 0].any()
    assert np.mean(ground[tree == 0]) > 0.5
    assert np.percentile(world[ground, 2], 99) < np.percentile(world[:, 2], 10) + 1.0
    # The technician's marks (the app's review) go into the inventory of a run
    # again, and so does a mark made after it.
    labels = [s["label"] for s in doc["scans"]]
    first = rows[0]["tree_id"]
    on_first = (float(rows[0]["x_m"]), float(rows[0]["y_m"]))  # its stem, upright
    # A tree added by hand on bare ground is listed apart, its figures none; a mark
    # kept under an id another run gave goes to the tree standing where it was given.
    write_review(
        out,
        labels,
        PlotReview(
            {"T099": "check"},
            dbh={first: HandCircle(on_first, 0.3)},
            added={"H001": (9.0, 9.0)},
            at={"T099": on_first},
        ),
    )
    capsys.readouterr()
    assert plot_main([*args, "--overwrite", "--report"]) == 0
    err = capsys.readouterr().err
    assert "wrote trees.csv, trees.xlsx, plot.json, view.npz, report.html" in err
    assert re.search(r"\n  DBH: \d+ ok.*; height: ", err)  # a first look
    assert not (out / "plot.laz").exists()  # it would not match this run's poses
    # The workbook says what each column holds, for a reader without the docs.
    import openpyxl

    from amrst.plot.export import INVENTORY_COLUMNS

    book = openpyxl.load_workbook(out / "trees.xlsx")
    notes = list(book["columns"].iter_rows(min_row=2, values_only=True))
    assert [c for c, _ in notes] == list(INVENTORY_COLUMNS)
    assert all(meaning for _, meaning in notes)
    assert book.properties.creator.startswith("AMRST ")
    assert _marks(out) == {first: "check"}
    assert read_review(out, labels).marks == {first: "check"}  # written so
    assert json.loads((out / "plot.json").read_text())["review_lost"] == []
    again = _rows_of(out)
    assert [r["dbh_hand_m"] for r in again] == ["0.3"] + [""] * (len(again) - 1)
    assert [r["tree_id"] for r in again] == [r["tree_id"] for r in rows] + ["H001"]
    assert again[-1]["n_points"] == "0"
    page = (out / "report.html").read_text()
    assert page.count("data:image/png;base64,") == 1  # the stem map, in the page
    assert f"<td>{first}</td>" in page
    assert "0 trees marked ok, 1 marked check, 0 marked not a tree and 1 DBH" in page
    doc = json.loads((out / "plot.json").read_text())
    residuals = [s["residual_m"] for s in doc["scans"]]
    assert all(0 < r < 0.02 for r in residuals)  # each scan on the other's surfaces
    assert doc["bundle_rmse_m"] == pytest.approx(np.sqrt(np.mean(np.square(residuals))))
    assert "<th>Residual</th>" in page
    assert 0 < doc["links"][0]["residual_m"] < 0.02
    assert f"<td>{100 * residuals[1]:.1f} cm</td>" in page
    assert f"Stand: {len(again)} trees" in page
    assert "2 registered" in page
    assert "cover an arc of 202.5° or more of the stem" in page  # what flags say
    # A mark no tree stands under any more is dropped, and the run says so.
    write_review(out, labels, PlotReview({"T050": "ok"}, at={"T050": (50.0, 50.0)}))
    capsys.readouterr()
    assert plot_main([*args, "--overwrite"]) == 0
    assert "where you gave T050 (ok): dropped" in capsys.readouterr().err
    assert json.loads((out / "plot.json").read_text())["review_lost"] == ["T050 (ok)"]
    assert read_review(out, labels).marks == {}
    trees = take_inventory([target, source], [np.eye(4), T_true]).trees
    marks = PlotReview({first: "ok", rows[1]["tree_id"]: "check"})
    write_inventory(out, trees, marks, None, unsure=())
    assert _marks(out) == {first: "ok", rows[1]["tree_id"]: "check"}
    # A review after the run does not wait for another writer of the folder.
    with FolderLock(out), pytest.raises(FolderBusy, match="another AMRST run"):
        write_inventory(out, trees, PlotReview({first: "check"}), None, unsure=())
    assert _marks(out) == {first: "ok", rows[1]["tree_id"]: "check"}
    assert plot_main([str(tmp_path / "missing.ply"), *args[1:]]) == 2
    (out / "review.json").write_text("{")
    assert plot_main([*args, "--overwrite"]) == 2  # refused before reading scans


def test_register_on_two_plot_scans_points_to_amrst_plot(
    plot_pair, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    from amrst.cli import main

    t, s = _pair_files(plot_pair, tmp_path)
    main(["register", str(t), str(s), "--out", str(tmp_path / "r"), "--quiet"])
    out = capsys.readouterr().out
    assert "a plot, not one tree" in out
    assert f"every tree: amrst plot {t} {s} --out DIR" in out
    assert "tree (merged)" not in out  # a plot is never described as one tree
    assert "the stem nearest the middle (merged)" in out


def test_a_run_keeps_each_scan_thinned_and_writes_every_point(
    plot_pair, tmp_path
) -> None:
    from amrst import io
    from amrst.errors import InvalidInput
    from amrst.plot.export import write_plot
    from amrst.plot.run import run_plot

    rng = np.random.default_rng(5)
    dense = [  # every point twice, a millimetre apart: denser than the stem map needs
        Cloud(np.vstack([c.xyz, c.xyz + rng.normal(0, 0.001, c.xyz.shape)]))
        for c in plot_pair[:2]
    ]
    files = _pair_files((*dense, None), tmp_path)
    run = run_plot([str(f) for f in files], tmp_path / "out", write_cloud=True)
    for kept, cloud in zip(run.registration.scans, dense, strict=True):
        assert kept.points_read == len(cloud)
        assert len(kept.analysis.cloud) < 0.6 * len(cloud)  # what the run holds
    merged = io.read(tmp_path / "out" / "plot.laz")  # read again: every point
    assert np.bincount(merged.attributes["scan_id"]).tolist() == [0, *map(len, dense)]
    for changed in (  # fewer points, or the same number moved 2 m
        plot_pair[1],
        dense[1].with_xyz(np.add(dense[1].xyz, (2.0, 0.0, 0.0))),
    ):
        io.write(files[1], changed)
        with pytest.raises(InvalidInput, match=r"s\.ply changed while the plot ran"):
            write_plot(
                tmp_path / "again",
                run.registration,
                run.inventory,
                run.labels,
                write_cloud=True,
            )


def _pair_files(plot_pair, folder: Path) -> list[Path]:
    """Write the plot pair's scans as t.ply and s.ply in ``folder``."""
    from amrst import io

    files = [folder / "t.ply", folder / "s.ply"]
    for f, c in zip(files, plot_pair[:2], strict=True):
        io.write(f, c)
    return files


def _reads_back(out: Path, T_true: np.ndarray) -> None:
    """The results folder holds what the app draws: trees, link poses, slices."""
    from amrst.errors import InvalidInput
    from amrst.plot.export import read_plot
    from amrst.plot.view import PROFILE_POINTS, SLICE_HEIGHTS_M, VIEW_NPZ

    files = read_plot(out)
    assert trees_csv(files.trees) == (out / TREES_CSV).read_text()
    (link,) = files.doc["links"]
    assert np.abs(np.array(link["T_target_source"]) - T_true).max() < 0.01
    assert link["pairs"] is None
    assert [s["unsure_links"] for s in files.doc["scans"]] == [[], []]
    for tree, slices in zip(files.trees, files.view.slices, strict=True):
        assert [s.height_m for s in slices] == list(SLICE_HEIGHTS_M)
        at_dbh = slices[1]  # the bark around the DBH circle, from both scans
        r = np.hypot(*(at_dbh.xy - tree.stem.dbh_xy).T)
        assert np.median(np.abs(r - tree.stem.dbh_m / 2)) < 0.01
        assert set(at_dbh.scan.tolist()) == {0, 1}
    for tree, side in zip(files.trees, files.view.profiles, strict=True):
        assert 0 < len(side.xyz) <= PROFILE_POINTS
        assert np.median(np.hypot(*(side.xyz[:, :2] - tree.stem.dbh_xy).T)) < 0.3
        assert np.ptp(side.xyz[:, 2]) > 0.8 * tree.stem.height_m
    view = (out / VIEW_NPZ).read_bytes()
    for cut in (view[:100], b""):
        (out / VIEW_NPZ).write_bytes(cut)
        with pytest.raises(InvalidInput, match=f"{VIEW_NPZ} cannot be read"):
            read_plot(out)
    (out / VIEW_NPZ).write_bytes(view)
    # A trees.csv cut off in its last row: a message, not a crash on the empty cells.
    table = (out / TREES_CSV).read_text()
    (out / TREES_CSV).write_text(table.rstrip("\n").rsplit(",", 12)[0] + "\n")
    last = len(table.splitlines()) - 1  # the header comes first
    with pytest.raises(InvalidInput, match=f"row {last} has too few cells"):
        read_plot(out)
    (out / TREES_CSV).write_text(table)
    # A named pipe in place of a file would block the reading for ever.
    for name in (VIEW_NPZ, TREES_CSV):
        kept = (out / name).read_bytes()
        (out / name).unlink()
        os.mkfifo(out / name)
        with pytest.raises(InvalidInput, match="is not a file"):
            read_plot(out)
        (out / name).unlink()
        (out / name).write_bytes(kept)


def _marks(out: Path) -> dict[str, str]:
    return {r["tree_id"]: r["mark"] for r in _rows_of(out) if r["mark"]}


def _rows_of(out: Path) -> list[dict[str, str]]:
    with (out / TREES_CSV).open() as fh:
        return list(csv.DictReader(fh))


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


def test_a_top_out_of_the_scanner_range_gives_no_height() -> None:
    stems = ((4.0, 0.0, 0.15, 14.0), (-3.0, 2.0, 0.12, 5.0), (0.0, -4.0, 0.1, 4.0))
    xyz = scan((0.0, 0.0), stems, 7)
    xyz = xyz[np.linalg.norm(xyz, axis=1) <= 10.0]  # the scanner's range
    inv = take_inventory([Cloud(xyz)], [np.eye(4)])
    trees = {round(float(t.xyz[0])): t.stem for t in inv.trees}
    assert {k: s.height_flag for k, s in trees.items()} == {
        4: "top out of range",
        -3: "ok",
        0: "ok",
    }
    # The 14 m tree was seen up to where the 10 m range cut it, and no higher.
    cut = trees[4]
    assert np.isnan(cut.height_m)
    assert 8.0 < cut.height_seen_m < 9.5
    assert np.isnan(trees[0].height_seen_m)
    assert cut.seen_to_m == cut.height_seen_m
    assert trees[0].seen_to_m == trees[0].height_m
    assert trees[0].height_m == pytest.approx(4.0, abs=0.3)
    row = next(t.row() for t in inv.trees if round(float(t.xyz[0])) == 4)
    assert row["height_m"] == ""
    assert row["height_seen_m"] == pytest.approx(cut.height_seen_m, abs=0.01)
    # Wherever a height is written out, such a tree reads "over how high it was seen".
    assert height_words(cut.height_m, cut.height_seen_m) == f">{cut.height_seen_m:.1f}"
    assert height_words(4.04, float("nan")) == "4.0"
    assert height_words(float("nan"), float("nan")) == "–"


def test_the_hidden_top_check_looks_from_where_the_file_says_the_scanner_stood() -> (
    None
):
    stems = ((4.0, 0.0, 0.15, 14.0), (-3.0, 2.0, 0.12, 5.0), (0.0, -4.0, 0.1, 4.0))
    xyz = scan((0.0, 0.0), stems, 7)
    xyz = xyz[np.linalg.norm(xyz, axis=1) <= 10.0]  # the scanner's range
    # The same scan posed into a project frame, as an E57 reader gives it.
    at = np.array([40.0, -25.0, 3.0])
    posed = Cloud(xyz + at, meta={"scanner_origin": tuple(at)})
    inv = take_inventory([posed], [np.eye(4)])
    flags = {round(float(t.xyz[0] - at[0])): t.stem.height_flag for t in inv.trees}
    assert flags == {4: "top out of range", -3: "ok", 0: "ok"}
    # A LAS file in its scanner's frame with a header offset: the file's origin.
    shift = np.array([20.0, 20.0, 0.0])
    shifted = Cloud(xyz + shift, offset=-shift)
    inv = take_inventory([shifted], [np.eye(4)])
    flags = {round(float(t.xyz[0])): t.stem.height_flag for t in inv.trees}
    assert flags == {4: "top out of range", -3: "ok", 0: "ok"}
    # Georeferenced, or moved a kilometre from its origin, a file does not say
    # where its scanner stood: no top is checked, and no height reads ok.
    for offset, moved in (((512_000.0, 5_400_000.0, 300.0), 0.0), (0.0, 1000.0)):
        far = Cloud(xyz + moved, offset=np.broadcast_to(offset, 3).astype(float))
        inv = take_inventory([far], [np.eye(4)])
        assert {t.stem.height_flag for t in inv.trees} == {"top not checked"}


def test_a_plot_of_posed_e57_scans_knows_where_each_scanner_stood(
    plot_pair, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    from _writers import write_e57

    from amrst.plot.view import scanner_position

    target, source, T_true = plot_pair
    # Each scan in its scanner's frame, posed into georeferenced coordinates.
    world = np.eye(4)
    world[:3, 3] = (512_000.0, 5_403_000.0, 310.0)
    stood = np.eye(4)
    stood[:3, 3] = (-2.0, 0.0, 0.0)  # the target's scanner in the plot fixture
    scans = [
        Cloud(target.xyz - stood[:3, 3], name="Setup A"),
        dataclasses.replace(source, name="Setup B"),
    ]
    e57 = tmp_path / "plot.e57"
    write_e57(e57, scans, [world @ stood, world @ T_true])
    out = tmp_path / "out"
    # Two positions of these six stems on flat ground: a half turn held by two stems
    # scores high, so the link may read needs review (exit 3); both scans are placed.
    args = [str(e57), "--out", str(out), "--quiet", "--plot-radius", "8", "--report"]
    assert plot_main(args) in (0, 3)
    doc = json.loads((out / "plot.json").read_text())
    assert all(s["reached"] for s in doc["scans"])
    # The setups' names in the file name the scans in plot.json and the report.
    assert [s["name"] for s in doc["scans"]] == ["Setup A", "Setup B"]
    assert "<td>Setup B</td>" in (out / "report.html").read_text()
    at = [scanner_position(s) for s in doc["scans"]]
    assert np.allclose(at[0], world[:3, 3] + (-2.0, 0.0, 0.0), atol=1e-6)
    assert np.allclose(at[1], (world @ T_true)[:3, 3], atol=0.05)
    # Without --plot-centre the plot is centred on the reference's scanner.
    area = doc["plot_area"]
    assert (area["centre_x_m"], area["centre_y_m"]) == pytest.approx(tuple(at[0][:2]))
    # The file says where its scanners stood: a --scanner is refused, not taken over it.
    given = ["--scanner", "1", *map(str, at[0])]
    assert plot_main([str(e57), "--out", str(tmp_path / "o2"), "--quiet", *given]) == 2
    # The whole file and one of its scans name that scan twice: refused unread.
    from amrst.io import scans as scans_module

    def no_read(spec, **_kw):
        raise AssertionError(f"{spec} was read")

    twice = [str(e57), f"{e57}#1", "--out", str(tmp_path / "o3"), "--quiet"]
    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(scans_module, "read_scans", no_read)
        assert plot_main(twice) == 2
    assert "plot.e57#1 is given twice" in capsys.readouterr().err


def test_scanners_given_by_hand_check_the_tops_of_georeferenced_scans(
    plot_pair, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    from amrst import io

    target, source, _ = plot_pair
    # Georeferenced LAS files that do not say where their scanners stood: the target
    # is in the plot's frame (its scanner at -2, 0), the source in its scanner's.
    geo = (
        np.array([512_000.0, 5_403_000.0, 310.0]),
        np.array([512_100.0, 5_403_050.0, 312.0]),
    )
    files = [tmp_path / "t.las", tmp_path / "s.las"]
    for f, xyz, g in zip(files, (target, source), geo, strict=True):
        io.write(f, Cloud(xyz.xyz, offset=g))
    args = [str(f) for f in files] + ["--quiet", "--out"]
    assert plot_main([*args, str(tmp_path / "a")]) in (0, 3)
    assert {r["height_flag"] for r in _rows_of(tmp_path / "a")} == {"top not checked"}

    stood = [geo[0] + (-2.0, 0.0, 0.0), geo[1]]
    given = [
        a
        for k, xyz in enumerate(stood)
        for a in ("--scanner", str(k + 1), *map(str, xyz))
    ]
    assert plot_main([*args, str(tmp_path / "b"), *given]) in (0, 3)
    assert "top not checked" not in {r["height_flag"] for r in _rows_of(tmp_path / "b")}
    doc = json.loads((tmp_path / "b" / "plot.json").read_text())
    assert [s["scanner_given"] for s in doc["scans"]] == [list(v) for v in stood]
    assert np.allclose(doc["scans"][0]["scanner_xyz"], stood[0], atol=1e-6)

    for bad, why in (
        (["0", "1", "2", "3"], "by its number from 1"),
        (["3", *map(str, stood[0])], "there are 2 scans"),
        (["1", "x", "0", "0"], "give X Y Z as numbers"),
        (["1", "1e300", "0", "0"], "at 1e300 0 0: give X Y Z as numbers within"),
    ):
        assert plot_main([*args, str(tmp_path / "c"), "--scanner", *bad]) == 2
        assert why in capsys.readouterr().err
    far = ["1", "0", "0", "0"]  # not in the file's coordinates
    high = [
        "1",
        *map(str, stood[0] + (0.0, 0.0, 60.0)),
    ]  # mistyped: far over the crowns
    aside = ["1", *map(str, stood[0] + (40.0, 40.0, 0.0))]  # beyond its scan's points
    for wrong in (far, high, aside):
        assert plot_main([*args, str(tmp_path / "c"), "--scanner", *wrong]) == 2
        assert "has no ground just below that point" in capsys.readouterr().err


def _stem(x: float, y: float, r: float, z0: float, z1: float) -> np.ndarray:
    """A whole cylinder of bark points (2 cm apart) from ``z0`` to ``z1``."""
    theta = np.linspace(0, 2 * np.pi, int(2 * np.pi * r / 0.02), endpoint=False)
    tt, zz = np.meshgrid(theta, np.arange(z0, z1, 0.02))
    return np.column_stack(
        [x + r * np.cos(tt.ravel()), y + r * np.sin(tt.ravel()), zz.ravel()]
    )


def _ground(half: float = 8.0) -> np.ndarray:
    g = np.mgrid[-half:half:0.08, -half:half:0.08].reshape(2, -1).T
    return np.column_stack([g, ground_z(g)])


def test_a_plot_that_lists_no_tree_says_why() -> None:
    from amrst.plot.inventory import take_inventory

    bare = take_inventory([Cloud(_ground(), name="g")], [np.eye(4)])
    assert not bare.trees
    assert bare.why_none.startswith("no stem stands on the ground found")
    upside_down = scan((0.5, 0.5), STEMS, 3) * [1.0, 1.0, -1.0]
    flipped = take_inventory([Cloud(upside_down, name="u")], [np.eye(4)])
    assert not flipped.trees
    assert "check that the scans are z-up" in flipped.why_none
    a = np.tile(np.linspace(0, 2 * np.pi, 60), 80)
    z = np.repeat(np.linspace(0, 8, 80), 60)
    stem = np.column_stack([0.2 * np.cos(a), 0.2 * np.sin(a), z])  # on no ground
    floating = take_inventory([Cloud(stem, name="f")], [np.eye(4)])
    assert not floating.trees
    assert floating.why_none.startswith("no ground was found under")
    listed = take_inventory([Cloud(scan((0.5, 0.5), STEMS, 3), name="s")], [np.eye(4)])
    assert listed.trees
    assert listed.why_none == ""


def test_crown_pieces_go_with_the_crown_they_continue() -> None:
    # A tall tree's branch droops over a small tree in pieces 0.3 m apart (a crown
    # seen in parts); its last piece hangs 1.2 m above the small tree's top.
    tall = _stem(0.0, 0.0, 0.15, -0.05, 10.0)
    small = _stem(4.0, 0.0, 0.06, 0.07, 4.0)
    pieces = [blob((0.3 + 0.7 * k, 0.0, 9.0 - 0.5 * k), 0.2, 300, k) for k in range(6)]
    xyz = np.vstack([_ground(), tall, small, *pieces])
    m = map_stems(xyz)
    heights = {round(float(s.base[0])): s.height_m for s in m.stems}
    assert heights[4] == pytest.approx(4.0, abs=0.2)
    assert heights[0] == pytest.approx(10.0, abs=0.2)


def test_a_stem_line_of_too_few_circles_has_no_lean_measured() -> None:
    from amrst.plot.stemmap import _stem_line

    base, _, lean = _stem_line([(0.6, 1.0, 2.0), (1.3, 1.2, 2.0)], np.zeros(2))
    np.testing.assert_allclose(base, [1.1, 2.0])
    assert np.isnan(lean)  # an upright stem assumed, not measured: trees.csv empty
    _, _, lean = _stem_line([(0.6, 1.0, 2.0), (1.3, 1.1, 2.0), (2.0, 1.2, 2.0)], base)
    assert lean == pytest.approx(np.degrees(np.arctan(0.1 / 0.7)))


def test_a_top_far_off_the_stem_s_foot_flags_the_height() -> None:
    # An upright 8 m stem whose top bends 3 m aside up to 10.4 m (a bent tree, or a
    # neighbour's crown taken as its top): 16 deg off the vertical over its foot.
    bent = _stem(0.0, 0.0, 0.15, -0.05, 8.0)
    top = [blob((0.5 * k, 0.0, 8.0 + 0.4 * k), 0.2, 300, k) for k in range(1, 7)]
    xyz = np.vstack([_ground(), bent, *top, _stem(-4.0, 0.0, 0.12, 0.0, 6.0)])
    stems = {round(float(s.base[0])): s for s in map_stems(xyz).stems}
    assert stems[0].lean_deg < 2  # the stem itself stands upright
    assert stems[0].height_m == pytest.approx(10.6, abs=0.3)
    assert (stems[0].height_flag, stems[-4].height_flag) == ("lean", "ok")
    upright = map_stems(xyz, StemMapParams(top_lean_flag_deg=20.0)).stems
    assert {s.height_flag for s in upright} == {"ok"}


def test_a_tree_given_by_hand_whose_top_stands_aside_is_flagged_too() -> None:
    # A stem seen to 0.8 m only (no tree of the map's own), then a limb rising 3 m
    # aside to 4.6 m: the technician's tree there reads its height, flagged lean.
    stub = _stem(0.0, 0.0, 0.1, -0.05, 0.8)
    t = np.linspace(0, 1, 3000)[:, None]
    noise = np.random.default_rng(3).normal(0, 0.04, (3000, 3))
    limb = np.array([0.0, 0.0, 0.8]) + t * np.array([3.0, 0.0, 3.8]) + noise
    given = map_stems(np.vstack([_ground(), stub, limb]), given={"H001": (0, 0)})
    (tree,) = given.stems
    assert tree.given == "H001"
    assert tree.height_m > 4
    assert tree.height_flag == "lean"


def test_a_tall_tree_under_a_broad_crown_keeps_its_top() -> None:
    # A pine seen only in rings 0.4 m apart from 4 to 8 m (a crown hides it) rises
    # through the 4.5 m wide crown of a lower tree standing 4 m away.
    pine = _stem(0.0, 0.0, 0.12, -0.05, 14.0)
    z = pine[:, 2]
    pine = pine[~((z > 4.0) & (z < 8.0) & ((z - 4.0) % 0.4 > 0.06))]
    rng = np.random.default_rng(1)
    r, a = 4.5 * np.sqrt(rng.uniform(0, 1, 40_000)), rng.uniform(0, 2 * np.pi, 40_000)
    crown = np.column_stack(
        [4.0 + r * np.cos(a), r * np.sin(a), rng.uniform(7.0, 9.0, 40_000)]
    )
    crown = crown[np.hypot(crown[:, 0], crown[:, 1]) > 0.2]  # round the pine
    xyz = np.vstack([_ground(), pine, _stem(4.0, 0.0, 0.2, 0.0, 7.0), crown])
    heights = {round(float(s.base[0])): s.height_m for s in map_stems(xyz).stems}
    assert heights[0] == pytest.approx(14.0, abs=0.2)
    assert heights[4] == pytest.approx(9.0, abs=0.2)


def test_a_twig_tip_of_two_points_is_the_top_and_one_point_is_a_stray() -> None:
    # A sparse crown's tip is often two beam hits on one twig, 0.6 m above the rest.
    tree = np.vstack([_ground(), _stem(0.0, 0.0, 0.15, -0.05, 10.0)])
    pair = np.array([[0.1, 0.0, 10.6], [0.12, 0.05, 10.62]])
    heights = [
        map_stems(np.vstack([tree, tip])).stems[0].height_m for tip in (pair, pair[:1])
    ]
    assert heights[0] - heights[1] == pytest.approx(0.6, abs=0.05)
    assert heights[1] == pytest.approx(10.0, abs=0.1)


def test_the_dbh_follows_the_stem_not_a_bulge_at_breast_height() -> None:
    xyz = scan((0.0, -4.0), ((0.0, 0.0, 0.12, 6.0), (3.0, 2.0, 0.1, 5.0)), 8)
    z0 = float(ground_z(np.zeros(2)))
    # The stem 3 cm thicker at 1.2-1.4 m (a burl, a whorl of branch stubs).
    ring = (np.hypot(xyz[:, 0], xyz[:, 1]) < 0.2) & (np.abs(xyz[:, 2] - z0 - 1.3) < 0.1)
    bulge = _stem(0.0, 0.0, 0.15, z0 + 1.2, z0 + 1.4)
    xyz = np.vstack([xyz[~ring], bulge[bulge[:, 1] < 0]])  # the side the scan sees
    key = map_stems(xyz, trees=False).stems
    tree = map_stems(xyz).stems
    at = int(np.argmin([np.hypot(*s.base[:2]) for s in tree]))
    assert tree[at].dbh_m == pytest.approx(0.24, abs=0.01)
    # The registration's key points keep the one bark circle at breast height.
    assert min(abs(s.dbh_m - 0.30) for s in key) < 0.01


def test_a_flared_foot_does_not_widen_the_dbh() -> None:
    # A 30 cm stem whose lowest slices still hold the flare of its roots.
    rings = [_stem(0.0, 0.0, 0.15, 1.15, 1.65)]
    rings += [_stem(0.0, 0.0, r, z, z + 0.06) for r, z in ((0.17, 0.96), (0.16, 1.06))]
    xyz = np.vstack(rings)
    taper = taper_dbh(xyz, xyz[:, 2], (np.zeros(2), np.zeros(2)), 0.15, 0.01)
    assert taper is not None
    # A least-squares line through the flare reads 8 mm more at 1.3 m.
    assert taper.dbh_m == pytest.approx(0.30, abs=0.001)


def test_a_stem_whose_slices_tell_several_diameters_has_no_dbh() -> None:
    xyz = scan((0.0, -4.0), ((0.0, 0.0, 0.15, 6.0), (3.0, 2.0, 0.1, 5.0)), 8)
    z0 = float(ground_z(np.zeros(2)))
    # Lobes at 1.0-1.6 m: four of the seven slices show the 30 cm stem.
    lobed = (np.hypot(xyz[:, 0], xyz[:, 1]) < 0.3) & (
        np.abs(xyz[:, 2] - z0 - 1.3) < 0.35
    )
    radii = (0.15, 0.25, 0.15, 0.15, 0.15, 0.11, 0.225)
    rings = [
        _stem(0.0, 0.0, r, z0 + at - 0.02, z0 + at + 0.02)
        for r, at in zip(radii, (1.0, 1.1, 1.2, 1.3, 1.4, 1.5, 1.6), strict=True)
    ]
    xyz = np.vstack([xyz[~lobed], *(ring[ring[:, 1] < 0] for ring in rings)])
    tree = map_stems(xyz).stems
    stem = tree[int(np.argmin([np.hypot(*s.base[:2]) for s in tree]))]
    assert np.isnan(stem.dbh_m)
    assert stem.dbh_quality == "none"
    assert stem.dbh_why.startswith("4 of 7 slice circles agree")


def test_a_stem_hidden_at_its_foot_is_a_tree_not_a_key_point() -> None:
    # Below 1.6 m the stem is out of sight; its own twigs fill 1.0-1.6 m around it.
    seen = scan((0.0, -5.0), ((0.0, 0.0, 0.12, 7.0), (3.0, 2.0, 0.1, 5.0)), 9)
    z0 = float(ground_z(np.zeros(2)))
    near = (np.hypot(seen[:, 0], seen[:, 1]) < 0.2) & (seen[:, 2] < z0 + 1.6)
    twigs = blob((0.0, 0.0, z0 + 1.3), 0.8, 6000, 10)
    twigs = twigs[
        (twigs[:, 2] > z0 + 1.0) & (np.hypot(twigs[:, 0], twigs[:, 1]) > 0.14)
    ]
    xyz = np.vstack([seen[~near], twigs])
    inv = take_inventory([Cloud(xyz)], [np.eye(4)])
    d = [np.hypot(*t.xyz[:2]) for t in inv.trees]
    assert len(inv.trees) == 2
    assert min(d) < 0.1
    assert min(np.hypot(*s.base[:2]) for s in map_stems(xyz, trees=False).stems) > 1


def test_a_top_hidden_behind_another_crown_is_flagged() -> None:
    stems = ((6.0, 0.0, 0.12, 5.0), (-3.0, 4.0, 0.12, 5.0))
    xyz = scan((0.0, 0.0), stems, 11)
    # A dense piece of some crown between the scanner and the first tree's top.
    xyz = np.vstack([xyz, blob((3.0, 0.0, 3.0), 0.5, 8000, 12)])
    inv = take_inventory([Cloud(xyz)], [np.eye(4)])
    flags = {round(float(t.xyz[0])): t.stem.height_flag for t in inv.trees}
    assert flags == {6: "top not seen", -3: "ok"}


def test_a_branch_drooping_to_the_ground_is_no_tree() -> None:
    xyz = scan((0.0, -5.0), ((0.0, 0.0, 0.15, 12.0), (-3.0, 3.0, 0.1, 5.0)), 13)
    z0 = float(ground_z(np.array([3.5, 0.0])))
    # The tall tree's branch bends down to 1.2 m above the ground 3.5 m away; its
    # tip shows a bark circle at breast height only, twigs and leaves hang around it.
    s = np.linspace(0.0, 1.0, 300)
    branch = np.column_stack([3.5 - 3.3 * s, 0.0 * s, z0 + 1.5 + 5.5 * s**2])
    tip = _stem(3.5, 0.0, 0.04, z0 + 1.2, z0 + 1.5)
    rng = np.random.default_rng(15)
    twigs = rng.uniform((3.2, -0.3, z0 + 0.35), (3.8, 0.3, z0 + 1.2), (600, 3))
    leaves = blob((3.5, 0.0, z0 + 2.0), 0.5, 3000, 14)
    pts = np.vstack([xyz, branch, tip[tip[:, 1] < 0], twigs, leaves])
    bases = sorted(np.round(s.base[:2]).tolist() for s in map_stems(pts).stems)
    assert bases == [[-3, 3], [0, 0]]
    # One bark circle taken as enough stem would list the tip as a 6 m tree.
    one_circle = replace(StemMapParams(), bark_heights=1)
    assert len(map_stems(pts, one_circle).stems) == 3


def test_stems_alone_hold_a_pose_only_with_a_clear_lead() -> None:
    def pose_of(stems: int, rms_m: float) -> StemPose:
        pairs = np.column_stack([np.arange(stems), np.arange(stems)])
        return StemPose(np.eye(4), pairs, rms_m, stems)

    assert held_by_stems([pose_of(5, 0.02), pose_of(2, 0.0)]) == 0
    assert held_by_stems([pose_of(4, 0.02)]) == 0
    # Fewer stems, a loose fit, or a rival as well confirmed: the points must judge.
    assert held_by_stems([pose_of(3, 0.02), pose_of(2, 0.0)]) is None
    assert held_by_stems([pose_of(5, 0.15), pose_of(2, 0.0)]) is None
    assert held_by_stems([pose_of(5, 0.02), pose_of(5, 0.03)]) is None
    assert held_by_stems([]) is None


def test_a_tilted_scans_stem_pose_meets_its_stems_at_breast_height() -> None:
    # The stems match by their breast-height circles; levelling the pose about the
    # ground under them would move those circles 1.3 m x sin(2.5°) = 5.7 cm.
    target = scan((-2.0, 0.0), STEMS, 1)
    T_true = pose(70.0, (3.0, 1.0, 0.0), tilt_deg=2.5)
    back = np.linalg.inv(T_true)
    source = scan((3.0, 1.0), STEMS, 2) @ back[:3, :3].T + back[:3, 3]
    best = stem_poses(map_stems(target, trees=False), map_stems(source, trees=False))[0]
    at = np.array(
        [(x, y, float(ground_z(np.array([x, y]))) + 1.3) for x, y, *_ in STEMS]
    )
    in_source = at @ back[:3, :3].T + back[:3, 3]
    T = best.T_target_source
    moved = in_source @ T[:3, :3].T + T[:3, 3]
    assert np.hypot(*(moved - at)[:, :2].T).max() < 0.015
    assert rotation_angle_deg(T[:3, :3] @ T_true[:3, :3].T) < 0.2


def test_stems_that_fix_the_heading_loosely_leave_a_held_pose_to_check(
    plot_scans, monkeypatch
) -> None:
    # Four wide stems close together, one with no circle: under a true pose each
    # could be off by a tenth of its width, which turns the plot's edge by decimetres.
    import amrst.plot.register as register

    thin_far = np.array([[0, 0, 1.3], [8, 0, 1.3], [0, 8, 1.3], [8, 8, 1.3]], float)
    wide_near = np.array([[0, 0, 1.3], [3, 0, 1.3], [0, 2, 1.3], [2, 3, 1.3]], float)
    thin = key_weights(np.full(4, 0.2), np.full(4, 0.21))
    wide = key_weights(
        np.array([1.1, 0.8, 0.6, np.nan]), np.array([1.2, 0.8, 0.6, 0.6])
    )
    assert _heading_sd_deg(thin_far, thin) < 0.2
    assert _heading_sd_deg(wide_near, wide) > HELD_HEADING_SD_DEG
    params, scans = plot_scans
    monkeypatch.setattr(register, "choose_coarse", lambda *a, **k: None)
    statuses = []
    found = stem_poses(scans[0].stems, scans[1].stems)[0].T_target_source
    for sd in (0.1, 0.6):
        held = StemPose(found, np.array([[k, k] for k in range(5)]), 0.03, 5, sd)
        monkeypatch.setattr(register, "stem_poses", lambda a, b, p=held: [p])
        link = register_plot_link(scans[0], scans[1], (0, 1), params).link
        statuses.append(link.status)
        assert link.origin == "stems"
    assert statuses == ["registered", "needs review"]
    assert "fix its heading to ±0.6° only" in link.message


def test_a_loose_stem_pose_is_refined_from_as_far_as_its_stems_missed(
    plot_pair, plot_scans, monkeypatch
) -> None:
    # Stems that meet within 12 cm leave the pose that far off at the stems, more at
    # the plot's edge: the fine registration must reach past the usual 20 cm first.
    import amrst.pipeline as pipeline
    import amrst.plot.register as register

    T_true = plot_pair[2]
    params, scans = plot_scans
    reaches = []
    refine = pipeline.refine

    def spy(*args, **kwargs):
        reaches.append(args[3].fine.max_corr_dist_m)
        return refine(*args, **kwargs)

    monkeypatch.setattr(pipeline, "refine", spy)
    for rms_m in (0.02, 0.12):
        loose = StemPose(T_true, np.array([[k, k] for k in range(5)]), rms_m, 5)
        monkeypatch.setattr(register, "stem_poses", lambda a, b, p=loose: [p])
        link = register_plot_link(scans[0], scans[1], (0, 1), params).link
        assert link.origin == "stems"
    assert reaches == [params.fine.max_corr_dist_m, pytest.approx(0.36)]


def test_a_stem_link_whose_fine_registration_did_not_converge_needs_review(
    plot_scans, monkeypatch
) -> None:
    # Stopped short, the fine registration can leave a pose between the right one and
    # where it started: such a link is not taken as registered, whatever its stems say.
    import amrst.pipeline as pipeline

    params, scans = plot_scans
    refine = pipeline.refine

    def stopped(*args, **kwargs):
        return replace(refine(*args, **kwargs), converged=False, iterations=100)

    monkeypatch.setattr(pipeline, "refine", stopped)
    link = register_plot_link(scans[0], scans[1], (0, 1), params).link
    assert link.verified
    assert link.status == "needs review"
    assert "did not converge after 100 iterations" in link.message
    assert link.as_dict()["fine_converged"] is False


def test_a_stem_seen_in_two_pieces_is_one_tree() -> None:
    xyz = scan((0.0, -5.0), ((4.0, 3.0, 0.12, 6.0),), 16)
    z0 = float(ground_z(np.zeros(2)))
    # Two positions north and south each see a quarter of a 24 cm stem: two pieces
    # too far apart to link, each a stem of its own in the slice.
    pieces = []
    for mid in (np.pi / 2, -np.pi / 2):
        theta = mid + np.linspace(-np.pi / 4, np.pi / 4, 25)
        tt, zz = np.meshgrid(theta, np.arange(z0 - 0.05, z0 + 4.0, 0.02))
        r = 0.12
        pieces.append(
            np.column_stack(
                [r * np.cos(tt.ravel()), r * np.sin(tt.ravel()), zz.ravel()]
            )
        )
    pts = np.vstack([xyz, *pieces])
    stems = map_stems(pts).stems
    assert len(stems) == 2
    at = min(stems, key=lambda s: float(np.hypot(*s.base[:2])))
    assert at.dbh_m == pytest.approx(0.24, abs=0.01)
    assert at.height_m == pytest.approx(4.0, abs=0.1)
    # Without the merge the one stem is two trees.
    apart = replace(StemMapParams(), same_stem_m=0.0)
    assert len(map_stems(pts, apart).stems) == 3


def test_a_leaning_stem_found_twice_above_its_foot_is_one_tree() -> None:
    from amrst.plot.stemmap import _merge_same_stems, _StemFit

    nan = float("nan")

    def fit(base_xy: tuple[float, float], line: list[tuple[float, ...]]) -> _StemFit:
        stem = StemRecord(
            np.r_[base_xy, 0.0], np.asarray(base_xy), nan, nan, nan, nan, "none",
            nan, "not measured", nan, nan, 10,
        )  # fmt: skip
        return _StemFit(stem, [(at, x, y) for at, x, y in line], {})

    # One stem leaning 11 degrees, found twice in its bark: the fit with circles at
    # 1.7 and 2.2 m stands it upright over them, the one with a circle at 1.0 m too
    # draws its lean down to the ground, 0.54 m away. The circles at 1.7 m meet.
    upright = fit((-2.31, 11.31), [(1.7, -2.28, 11.37), (2.2, -2.35, 11.26)])
    drawn = fit((-1.93, 11.70), [(1.0, -2.12, 11.5), (1.7, -2.27, 11.38)])
    # A neighbour 0.6 m off, its circle at 1.7 m as far.
    neighbour = fit((-1.68, 11.37), [(1.7, -1.67, 11.37)])
    seeds = [np.array([0]), np.array([1]), np.array([2])]
    fits: list[_StemFit | None] = [upright, drawn, neighbour]
    _merge_same_stems(seeds, fits, StemMapParams())
    assert [f is not None for f in fits] == [True, False, True]
    assert seeds[0].tolist() == [0, 1]


def test_the_arc_seen_decides_a_dbh_and_its_flag() -> None:
    def arc(x: float, r: float, half_deg: float) -> np.ndarray:
        z0 = float(ground_z(np.array([x, 0.0])))
        cyl = _stem(x, 0.0, r, z0 - 0.05, z0 + 6.0)
        # Seen from -y: the bark within half_deg of facing the scanner.
        facing = np.degrees(np.arctan2(cyl[:, 1], cyl[:, 0] - x)) + 90.0
        return cyl[np.abs((facing + 180.0) % 360.0 - 180.0) <= half_deg]

    xyz = np.vstack(
        [
            _ground(10.0),
            arc(-6.0, 0.1, 110.0),
            arc(-3.0, 0.4, 65.0),
            arc(0.0, 0.1, 65.0),
            arc(3.0, 0.4, 110.0),
            arc(6.0, 0.1, 90.0),
            arc(9.0, 0.4, 130.0),
        ]
    )
    dbh = {round(float(s.base[0])): s for s in map_stems(xyz).stems}
    assert dbh[-3].dbh_quality == "none"  # 80 cm wide, 130 deg of it
    assert dbh[-3].dbh_why.startswith("a wide stem seen on 1")
    assert dbh[0].dbh_m == pytest.approx(0.2, abs=0.01)  # 20 cm, 130 deg: round
    assert dbh[3].dbh_m == pytest.approx(0.8, abs=0.02)  # 80 cm, 220 deg
    # A circle on half the bark or less is not bounded on both sides: check it.
    assert dbh[6].dbh_m == pytest.approx(0.2, abs=0.01)  # 20 cm, 180 deg
    assert dbh[6].dbh_quality == "check"
    assert dbh[6].dbh_why.startswith("bark seen on 1")
    assert dbh[6].dbh_why.endswith(", 202.5° needed")
    assert (dbh[-6].dbh_quality, dbh[-6].dbh_why) == ("ok", "")  # 20 cm, 220 deg
    # A wide stem is seldom round: ok only from two thirds of its bark.
    assert dbh[3].dbh_quality == "check"  # 80 cm, 220 deg
    assert dbh[3].dbh_why.endswith(", 240° needed")
    assert dbh[9].dbh_m == pytest.approx(0.8, abs=0.02)  # 80 cm, 260 deg
    assert dbh[9].dbh_quality == "ok"


def test_stems_outvote_only_an_unsure_winner_they_do_not_hold() -> None:
    from types import SimpleNamespace

    from amrst.plot.register import _outvoted
    from amrst.review.manual import MANUAL_ID_BASE

    def winner(pose: int, confidence: float) -> SimpleNamespace:
        cand = SimpleNamespace(id=MANUAL_ID_BASE + pose)
        return SimpleNamespace(candidate=cand, confidence=confidence)

    assert _outvoted(winner(1, 0.05), held=0)  # unsure, another pose held
    assert not _outvoted(winner(0, 0.05), held=0)  # the held pose itself
    assert not _outvoted(winner(1, 0.9), held=0)  # sure: the points decide
    assert not _outvoted(winner(1, 0.05), held=None)  # no pose held


def test_a_tree_stands_where_its_stem_leaves_the_ground() -> None:
    # An upright broadleaf: root flare below 0.9 m, a fork at 1.65 m, and between
    # 1.0 and 1.6 m a sweep of 8 cm, so the stem line through its circles leans;
    # drawn down to the ground it would put the tree 12 cm off its foot.
    z0 = float(ground_z(np.zeros(2)))
    hz = np.arange(-0.05, 1.65, 0.02)
    r = 0.15 + 0.06 * np.clip((0.9 - hz) / 0.4, 0.0, 1.0)
    x = 0.08 * np.clip((hz - 1.0) / 0.6, 0.0, 1.0)
    rings = zip(x, r, hz, strict=True)
    trunk = np.vstack(
        [_stem(xi, 0.0, ri, z0 + h, z0 + h + 0.02) for xi, ri, h in rings]
    )
    forks = [_stem(0.08, dy, 0.09, z0 + 1.65, z0 + 8.0) for dy in (-0.1, 0.1)]
    tree = map_stems(np.vstack([_ground(), trunk, *forks])).stems
    assert len(tree) == 1
    assert tree[0].dbh_m == pytest.approx(0.3, abs=0.01)
    assert np.hypot(*tree[0].base[:2]) < 0.02


def test_a_buttress_round_the_foot_does_not_move_the_tree() -> None:
    # From 0.45 to 0.75 m a buttress wraps the stem on one side: the circle there
    # goes round it, twice as wide and 30 cm off, where the tree does not stand.
    z0 = float(ground_z(np.zeros(2)))
    trunk = [
        _stem(0.0, 0.0, 0.15, z0 - 0.05, z0 + 0.45),
        _stem(0, 0, 0.15, z0 + 0.75, z0 + 8),
    ]
    wide = _stem(0.3, 0.0, 0.35, z0 + 0.45, z0 + 0.75)
    tree = map_stems(np.vstack([_ground(), *trunk, wide])).stems
    assert len(tree) == 1
    assert tree[0].dbh_m == pytest.approx(0.3, abs=0.01)
    assert np.hypot(*tree[0].base[:2]) < 0.05


def test_tree_clouds_of_an_earlier_run_do_not_outlive_it(plot_pair, tmp_path: Path):
    from amrst import io

    target = plot_pair[0]
    files = _pair_files(plot_pair, tmp_path)
    out = tmp_path / "out"
    args = [*map(str, files), "--out", str(out), "--quiet", "--overwrite"]
    assert plot_main([*args, "--write-trees"]) == 0
    clouds = sorted(p.name for p in (out / "trees").glob("*.ply"))
    assert len(clouds) == len(STEMS)
    # A tree only an earlier run listed, and a file of the user's named like one.
    io.write(out / "trees" / "T099.ply", target)
    with (out / "trees.csv").open("a") as fh:
        fh.write("T099\n")
    io.write(out / "trees" / "T098.ply", target)
    assert plot_main([*args, "--write-trees"]) == 0
    kept = sorted(p.name for p in (out / "trees").glob("*.ply"))
    assert kept == sorted([*clouds, "T098.ply"])
    assert plot_main(args) == 0
    assert [p.name for p in (out / "trees").glob("*.ply")] == ["T098.ply"]
    # Tree clouds beside no readable trees.csv: --overwrite replaces them all.
    for name in ("plot.json", "trees.csv"):
        (out / name).unlink()
    assert plot_main(args) == 0
    assert not list((out / "trees").glob("*.ply"))


def test_a_run_keeps_what_is_not_its_own_and_refuses_inputs_it_would_replace(
    plot_pair, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    from amrst import io

    target = plot_pair[0]
    files = _pair_files(plot_pair, tmp_path)
    out = tmp_path / "out"
    (out / "trees").mkdir(parents=True)
    io.write(out / "trees" / "my_scan.ply", target)  # not a tree cloud of a run
    args = [*map(str, files), "--out", str(out), "--quiet"]
    assert plot_main([*args, "--report", "--plot-radius", "6"]) == 0
    report = (out / "report.html").read_text()
    area = json.loads((out / "plot.json").read_text())["plot_area"]
    assert area["radius_m"] == 6.0
    assert area["hectares"] == pytest.approx(np.pi * 6.0**2 / 1e4, rel=1e-4)
    assert "stems/ha" in report
    assert "<th>In the plot</th>" in report  # and its edge on the stem map
    assert "stand within 6\u00a0m (0.0113\u00a0ha): 4 trees" in capsys.readouterr().err
    inside = {
        r["tree_id"]: "yes"
        if np.hypot(float(r["x_m"]), float(r["y_m"])) <= 6.0
        else "no"
        for r in _rows_of(out)
    }
    assert {r["tree_id"]: r["in_plot"] for r in _rows_of(out)} == inside
    assert sorted(inside.values()) == ["no", "no", "yes", "yes", "yes", "yes"]
    # A plot that leaves out every listed tree is said, with what to check.
    from amrst.plot.cli import _say_stand
    from amrst.plot.stand import PlotArea

    _say_stand(out, PlotArea((30.0, 30.0), 2.0))
    assert "no listed tree stands within 2 m of (30.00, 30.00)" in (
        capsys.readouterr().err
    )
    assert plot_main([*args, "--overwrite"]) == 0
    assert not (out / "report.html").exists()  # it described the earlier run
    assert (out / "trees" / "my_scan.ply").is_file()
    capsys.readouterr()
    refused = {
        "given twice": [str(files[0]), str(files[0]), "--out", str(tmp_path / "a")],
        "same points": [str(files[0]), str(tmp_path / "copy.ply"), "--out", "b"],
        "the run writes": [str(out / "trees" / "T001.ply"), str(files[1]), "--out"],
        "is a file": [*map(str, files), "--out", str(files[0])],
        "--out is empty": [*map(str, files), "--out", " "],
        "twice: give one pairs file": [
            *map(str, files),
            *("--out", str(tmp_path / "c")),
            *("--pairs", "1", "2", "p.csv", "--pairs", "2", "1", "q.csv"),
        ],
        "needs the plot's radius": [
            *map(str, files),
            *("--out", str(tmp_path / "d"), "--plot-centre", "1", "2"),
        ],
        "radius must be a distance": [  # before any scan is read
            *(str(files[0]), str(tmp_path / "not_yet_scanned.ply")),
            *("--out", str(tmp_path / "e"), "--plot-radius", "nan"),
        ],
        "(georeferenced?)": [
            str(tmp_path / "far.ply"),
            str(files[1]),
            *("--out", str(tmp_path / "f"), "--plot-radius", "15"),
        ],
        "give a larger radius": [  # a circle that holds nothing, near the points
            *map(str, files),
            *("--out", str(tmp_path / "h"), "--plot-radius", "0.5"),
            *("--plot-centre", "0", "40"),  # beyond the scans' edge
        ],
        "holds none of": [  # a centre typed in other coordinates
            *map(str, files),
            *("--out", str(tmp_path / "g"), "--plot-radius", "15"),
            *("--plot-centre", "500000", "4000000"),
        ],
    }
    far = replace(target, xyz=target.xyz + np.array([5e5, 4e6, 0.0]))
    io.write(tmp_path / "far.ply", far)
    io.write(tmp_path / "copy.ply", target)
    io.write(out / "trees" / "T001.ply", target)
    refused["the run writes"].append(str(out))
    for words, argv in refused.items():
        assert plot_main([*argv, "--quiet", "--overwrite"]) == 2, words
        err = capsys.readouterr().err
        assert words in err, err
        assert err.count("\n") == 1, err


def test_a_review_that_cannot_be_right_is_refused(tmp_path: Path) -> None:
    from amrst.errors import InvalidInput

    bad = {
        "no review file: its 'scans' is not what the app writes": {
            "scans": 5,
            "marks": {},
        },
        "no review file: it has no 'marks'": {"scans": []},
        "its 'dbh' is not what the app writes; move": {
            "scans": [],
            "marks": {},
            "dbh": {"T001": {"x_m": 1.0, "y_m": 2.0}},
        },
        "its 'at' is not what the app writes; move": {
            "scans": [],
            "marks": {},
            "at": {"T001": [1.0, 2.0, 3.0]},
        },
        "not a rotation": {
            "scans": [],
            "marks": {},
            "accepted": {"1-2": np.diag([2.0, 2, 2, 1])},
        },
        "NaN/inf": {
            "scans": [],
            "marks": {},
            "accepted": {"1-2": np.full((4, 4), np.nan)},
        },
        "out of any plot": {
            "scans": [],
            "marks": {},
            "added": [{"id": "H001", "x_m": 1e300, "y_m": 0}],
        },
        "not H and a number": {
            "scans": [],
            "marks": {},
            "added": [{"id": "../../target", "x_m": 1, "y_m": 0}],
        },
    }
    for words, doc in bad.items():
        text = json.dumps(doc, default=lambda a: a.tolist())
        (tmp_path / "review.json").write_text(text)
        with pytest.raises(InvalidInput, match=words):
            read_review(tmp_path, [])
    (tmp_path / "review.json").write_text("[1, 2]")
    with pytest.raises(InvalidInput, match="no review file: it is no JSON object"):
        read_review(tmp_path, [])
    (tmp_path / "review.json").write_text("[" * 100_000)
    with pytest.raises(InvalidInput, match="no review file"):
        read_review(tmp_path, [])
    (tmp_path / "review.json").unlink()
    (tmp_path / "review.json").mkdir()
    with pytest.raises(InvalidInput, match="not a file"):
        read_review(tmp_path, [])


def test_a_tree_added_out_of_every_scan_s_sight_is_not_listed(
    plot_pair, tmp_path: Path
) -> None:
    files = _pair_files(plot_pair, tmp_path)
    out = tmp_path / "out"
    labels = [str(f.resolve()) for f in files]
    out.mkdir()
    write_review(out, labels, PlotReview(added={"H001": (900.0, 900.0)}))
    assert plot_main([*labels, "--out", str(out), "--quiet"]) == 0
    rows = _rows_of(out)
    assert "H001" not in {r["tree_id"] for r in rows}
    assert json.loads((out / "plot.json").read_text())["review_lost"] == [
        "H001 (added)"
    ]
    assert read_review(out, labels).added == {}


def _whorls(
    centre: tuple[float, float],
    rng: np.random.Generator,
    low: float = 2.0,
    step: float = 0.4,
    length: float = 1.2,
) -> np.ndarray:
    """A spruce without its stem: whorls of 8 level branches from ``low`` to 12 m."""
    parts = []
    for z in np.arange(low, 12.0, step):
        for a in rng.uniform(0, 2 * np.pi) + np.arange(8) * np.pi / 4:
            t = rng.uniform(0.1, length, 60)
            parts.append(
                np.column_stack(
                    [
                        centre[0] + t * np.cos(a),
                        centre[1] + t * np.sin(a),
                        z - 0.1 * t + rng.normal(0, 0.005, 60),
                    ]
                )
            )
    return np.vstack(parts)


def test_branch_axis_finds_the_stem_its_branches_radiate_from() -> None:
    rng = np.random.default_rng(3)
    tree = _whorls((1.0, -2.0), rng)
    # Only one side seen, and the search starts 0.8 m off.
    tree = tree[tree[:, 0] > 0.7]
    axis = branch_axis(tree, tree[:, 2], np.array([1.6, -1.5]))
    assert axis is not None
    assert np.hypot(*(axis[0] - (1.0, -2.0))) < 0.05
    assert axis[1] > 0.8
    # Branches in every direction from nowhere in particular: few pass one point.
    tree = _whorls((0.0, 0.0), rng)
    tree[:, :2] += rng.uniform(-1.5, 1.5, (len(tree) // 60, 2)).repeat(60, axis=0)
    axis = branch_axis(tree, tree[:, 2], np.zeros(2))
    assert axis is None or axis[1] < 0.25


def test_a_spruce_wrapped_in_its_branches_is_listed_without_dbh() -> None:
    # Whorls from 0.4 m up hide the stem from every side, in a skirt 2.8 m wide:
    # wider than a stem's slice cluster, and no bark circle anywhere.
    spruce = _whorls((2.0, 1.0), np.random.default_rng(5), 0.4, 0.15, 1.4)
    spruce[:, 2] += ground_z(np.array([[2.0, 1.0]]))[0]
    xyz = np.vstack([_ground(), spruce, _stem(-4.0, 0.0, 0.12, 0.0, 6.0)])
    trees = {round(float(s.base[0])): s for s in map_stems(xyz).stems}
    assert sorted(trees) == [-4, 2]
    wrapped = trees[2]
    assert np.hypot(*(wrapped.base[:2] - (2.0, 1.0))) < 0.1
    assert np.isnan(wrapped.dbh_m)
    assert wrapped.dbh_why == "the stem is hidden in its branches"
    assert wrapped.height_m == pytest.approx(12.0, abs=0.5)
    assert wrapped.height_flag == "ok"
    # The registration's stem map lists stems on their bark circles alone.
    assert len(map_stems(xyz, trees=False).stems) == 1
    # A neighbour's limb rising 2.2 m aside of its top to 13 m (under 10 degrees off
    # its foot): a conifer's top stands over its stem, so this one is flagged.
    t = np.linspace(0, 1, 2000)[:, None]
    noise = np.random.default_rng(4).normal(0, 0.03, (2000, 3))
    limb = np.array([2.6, 1.0, 11.4]) + t * np.array([1.6, 0.0, 1.6]) + noise
    limb[:, 2] += ground_z(np.array([[2.0, 1.0]]))[0]
    trees = {
        round(float(s.base[0])): s for s in map_stems(np.vstack([xyz, limb])).stems
    }
    assert trees[2].height_m == pytest.approx(13.0, abs=0.3)
    assert trees[2].height_flag == "lean"


def test_circles_through_branches_scatter_and_a_stem_s_do_not() -> None:
    from amrst.plot.stemmap import _scattered

    params = StemMapParams()
    leaning = [(z, 0.15 * z, 0.0) for z in (0.6, 1.0, 1.3, 1.7, 2.2)]  # 8.5 deg
    assert not _scattered(leaning, params)
    branches = [(0.6, 0.0, 0.0), (1.0, -0.4, 0.5), (1.3, 0.1, 0.2), (1.7, -0.4, 0.0)]
    assert _scattered(branches, params)
    assert not _scattered([], params)


def test_a_tree_the_technician_gives_is_listed_apart(plot_pair) -> None:
    target, source, T_true = plot_pair
    clouds, poses = [target, source], [np.eye(4), T_true]
    found = take_inventory(clouds, poses)
    bush = (-1.0, -1.5)  # a small stem the map does not take for a tree
    small = scan((-2.0, 0.0), ((*bush, 0.03, 1.5),), 7)
    clouds = [Cloud(np.vstack([target.xyz, small])), source]
    plain = take_inventory(clouds, poses)
    assert len(plain.trees) == len(STEMS)
    # Given where it stands, on a listed tree (kept as it is), and on bare ground.
    on_tree = tuple(found.trees[0].stem.base[:2])
    ground = (9.0, 9.0)
    given = {"H001": bush, "H002": on_tree, "H003": ground}
    inv = take_inventory(clouds, poses, given=given)
    # The trees found keep their ids and figures; the given ones are numbered apart.
    assert [t.tree_id for t in inv.trees] == [
        *(t.tree_id for t in plain.trees),
        "H001",
        "H003",
    ]
    assert [t.row() for t in inv.trees[: len(STEMS)]] == [t.row() for t in plain.trees]
    given, bare = inv.trees[len(STEMS) :]
    assert np.hypot(*(given.xyz[:2] - bush)) < 0.1
    assert abs(given.stem.dbh_m - 0.06) < 0.01
    assert np.hypot(*(bare.xyz[:2] - ground)) < 1e-9
    assert np.isnan(bare.stem.dbh_m)
    assert bare.stem.dbh_quality == "none"
    # Two points on one spot: two trees given, each listed.
    twice = take_inventory(clouds, poses, given={"H001": ground, "H002": ground})
    assert [t.tree_id for t in twice.trees][-2:] == ["H001", "H002"]


def test_a_stem_the_map_missed_is_listed_where_given(
    plot_pair, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A real stem found only through the technician's point keeps its H id, and the
    trees found keep theirs."""
    from amrst.plot import stemmap

    target, source, T_true = plot_pair
    clouds, poses = [target, source], [np.eye(4), T_true]
    missed = np.array(STEMS[0][:2])  # (0, 4), 30 cm
    find = stemmap.find_stems

    def blind(pts, h, above, params):  # the slice finds every stem but this one
        found, lab, idx = find(pts, h, above, params)
        near = [
            k
            for k in range(len(found))
            if np.hypot(*(pts[idx[lab == k], :2].mean(axis=0) - missed)) < 0.5
        ]
        lab = np.where(np.isin(lab, near), -1, lab)
        keep = [k for k in range(len(found)) if k not in near]
        lab = np.where(lab >= 0, np.searchsorted(keep, lab), -1)
        return [found[k] for k in keep], lab, idx

    monkeypatch.setattr(stemmap, "find_stems", blind)
    monkeypatch.setattr(stemmap, "bark_seeds", lambda *_a: [])
    plain = take_inventory(clouds, poses)
    assert len(plain.trees) == len(STEMS) - 1
    inv = take_inventory(clouds, poses, given={"H001": tuple(missed)})
    assert [t.tree_id for t in inv.trees] == [t.tree_id for t in plain.trees] + ["H001"]
    assert [t.row() for t in inv.trees[:-1]] == [t.row() for t in plain.trees]
    assert abs(inv.trees[-1].stem.dbh_m - 2 * STEMS[0][2]) < 0.02


def test_a_scanner_position_far_off_its_points_is_not_where_it_stood() -> None:
    from amrst.plot.inventory import ORIGIN_GAP_M, scanner_at

    xyz = np.random.default_rng(0).uniform(-10, 10, (500, 3))
    near = Cloud(xyz, meta={"scanner_origin": (1.0, 2.0, 1.5)})
    np.testing.assert_allclose(scanner_at(near), (1.0, 2.0, 1.5))
    # A file's header (PTX) that says 1000 km: its sight lines would cross the world.
    far = Cloud(xyz, meta={"scanner_origin": (1e6, 0.0, 0.0)})
    assert scanner_at(far) is None
    edge = Cloud(xyz, meta={"scanner_origin": (10.0 + ORIGIN_GAP_M / 2, 0.0, 0.0)})
    assert scanner_at(edge) is not None


def test_a_scan_of_ground_only_is_named_with_its_stems_when_it_fails(
    plot_pair, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    from amrst import io

    target, source, _T = plot_pair
    files = [tmp_path / "t.ply", tmp_path / "s.ply", tmp_path / "ground.ply"]
    for path, cloud in zip(
        files, (target, source, Cloud(scan((1.0, 1.0), (), 5))), strict=True
    ):
        io.write(path, cloud)
    code = plot_main([*map(str, files), "--out", str(tmp_path / "o"), "--quiet"])
    assert code == 3
    err = capsys.readouterr().err
    assert "not registered (no verified link): " in err
    assert "ground.ply (0 stems found)" in err
    assert "the reference" not in err  # the first scan shows its stems
    # Given first, the scan without stems is the one to change, not the others.
    files.insert(0, files.pop())
    out = tmp_path / "first"
    code = plot_main([*map(str, files), "--out", str(out), "--quiet"])
    assert code == 3
    err = capsys.readouterr().err
    assert f"the reference, {files[0]}, shows no stem: give first a scan" in err
    # A scan exported Y-up: the command and plot.json say how it seems to stand.
    y_up = Cloud(source.xyz[:, [0, 2, 1]] * [1.0, 1.0, -1.0], name="y")
    io.write(tmp_path / "y_up.ply", y_up)
    out = tmp_path / "y_up"
    args = [str(tmp_path / "t.ply"), str(tmp_path / "y_up.ply"), "--out", str(out)]
    assert plot_main([*args, "--quiet"]) == 3
    err = capsys.readouterr().err
    assert "found; it seems to stand with its y axis up: export it z up)" in err
    doc = json.loads((out / "plot.json").read_text())
    assert [s["turned"] for s in doc["scans"]] == ["", "with its y axis up"]


def test_a_scanner_may_be_given_where_the_file_says_nothing_usable() -> None:
    from amrst.errors import InvalidInput
    from amrst.plot.run import _with_scanner

    xy = np.mgrid[-5:5:0.2, -5:5:0.2].reshape(2, -1).T
    ground = np.column_stack([xy, np.zeros(len(xy))])
    told = Cloud(ground, meta={"scanner_origin": (0.5, 0.5, 1.5)})
    with pytest.raises(InvalidInput, match="says where its scanner stood"):
        _with_scanner(told, 0, "a.ptx", (0.0, 0.0, 1.5))
    # A header 1000 km off its points: no scanner known, so one may be given.
    far = Cloud(ground, meta={"scanner_origin": (1e6, 0.0, 0.0)})
    given = _with_scanner(far, 0, "a.ptx", (0.0, 0.0, 1.5))
    assert given.meta["scanner_origin"] == (0.0, 0.0, 1.5)


def test_a_scan_a_plot_run_would_write_over_is_refused_unread(
    plot_pair, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    from amrst import io

    out = tmp_path / "out"
    (out / "trees").mkdir(parents=True)
    other = tmp_path / "s.ply"
    io.write(other, plot_pair[1])
    for inside in (
        out / "trees.csv",
        out / "trees" / "T001.ply",
        out / "trees" / "x.ply",
    ):
        io.write(inside.with_suffix(".ply"), plot_pair[0])
        scan = inside.with_suffix(".ply")
        if inside.suffix == ".csv":  # named as the run's trees.csv
            scan = scan.rename(inside)
        before = scan.read_bytes()
        args = [str(scan), str(other), "--out", str(out), "--quiet", "--overwrite"]
        assert plot_main(args) == 2
        assert "is a file the run writes in" in capsys.readouterr().err
        assert scan.read_bytes() == before


def test_a_tree_without_a_stem_fit_has_no_arc_nor_lean() -> None:
    # A tree given where nothing stands: no circle, so no arc seen and no lean (an
    # upright 0.0 would read as measured).
    (tree,) = map_stems(_ground(), given={"H001": (3.0, 3.0)}).stems
    assert tree.dbh_quality == "none"
    assert np.isnan(tree.arc_deg)
    assert np.isnan(tree.lean_deg)
    assert tree.height_flag == "not measured"


def test_plot_json_names_a_loop_s_scans_as_its_links_do() -> None:
    from amrst.plot.export import _loops

    assert _loops({"0-2": 0.5, "1-2": 0.1}) == [
        {"target": 0, "source": 2, "m": 0.5},
        {"target": 1, "source": 2, "m": 0.1},
    ]


def test_a_run_does_not_replace_what_another_run_wrote_meanwhile(
    plot_pair, tmp_path, monkeypatch
) -> None:
    from _writers import written_first

    from amrst.files.outdir import FolderChanged
    from amrst.plot import inventory
    from amrst.plot.run import run_plot

    files = [str(f) for f in _pair_files(plot_pair, tmp_path)]
    out = tmp_path / "out"
    taken = inventory.take_inventory
    another_run = written_first(taken, out / "plot.json", '{"scans": []}')
    monkeypatch.setattr(inventory, "take_inventory", another_run)
    with pytest.raises(FolderChanged, match="another run wrote it"):
        run_plot(files, out)
    assert (out / "plot.json").read_text() == '{"scans": []}'
    assert not (out / "trees.csv").exists()
    monkeypatch.setattr(inventory, "take_inventory", taken)
    run_plot(files, out, overwrite=True)  # asked to replace what it finds: it does
    assert (out / "trees.csv").is_file()


def test_one_scan_in_two_formats_is_refused_as_one_scan(plot_pair, tmp_path) -> None:
    from amrst import io
    from amrst.errors import InvalidInput
    from amrst.plot.run import run_plot

    t, _ = _pair_files(plot_pair, tmp_path)
    io.write(tmp_path / "t.las", plot_pair[0])  # the same scan, in millimetres
    with pytest.raises(InvalidInput, match=r"t\.las holds the same points as"):
        run_plot([str(t), str(tmp_path / "t.las")], tmp_path / "out")


def test_a_stem_hidden_for_a_metre_keeps_its_top_from_a_neighbour_s_crown() -> None:
    """A's stem is hidden 6-7.2 m up, where B's crown reaches it: without A's stem
    followed up, B took A's upper stem and top (6 m and 14 m instead of 14 and 9)."""
    rng = np.random.default_rng(3)
    stems = ((0.0, 0.0, 0.08, 14.0), (1.8, 0.0, 0.2, 9.0))  # A thin and tall, B
    xyz = scan((-6.0, 0.5), stems, seed=1)
    h = xyz[:, 2] - ground_z(xyz[:, :2])
    hidden = (np.hypot(xyz[:, 0], xyz[:, 1]) < 0.3) & (h > 6.0) & (h < 7.2)
    r, a = 1.8 * np.sqrt(rng.uniform(0, 1, 8000)), rng.uniform(0, 2 * np.pi, 8000)
    crown = np.column_stack(  # B's crown, 7-9 m, up to A's stem
        [1.8 + r * np.cos(a), r * np.sin(a), rng.uniform(7.0, 9.0, 8000)]
    )
    crown = crown[np.hypot(crown[:, 0], crown[:, 1]) > 0.15]
    top = np.column_stack(  # A's crown, 12.5-14 m
        [rng.normal(0, 0.5, (1500, 2)), rng.uniform(12.5, 14.0, 1500)]
    )
    for part in (crown, top):
        part[:, 2] += ground_z(part[:, :2])
    m = map_stems(np.vstack([xyz[~hidden], crown, top]))
    heights = {round(float(s.base[0]), 1): s.height_m for s in m.stems}
    assert heights[0.0] == pytest.approx(14.0, abs=0.3)
    assert heights[1.8] == pytest.approx(9.0, abs=0.3)


@pytest.mark.skipif(not os.path.isdir("/proc/self"), reason="no /proc")
def test_a_results_folder_that_cannot_be_made_is_refused_before_the_run() -> None:
    import pathlib

    from amrst.errors import InvalidInput
    from amrst.plot.export import check_out

    # /proc lets root "write" by its permissions, but no folder can be made in it.
    with pytest.raises(InvalidInput, match=r"Cannot create the results folder /proc/"):
        check_out(pathlib.Path("/proc/amrst-no-such-folder"), overwrite=False)


def test_a_scan_turned_over_is_told_which_way_it_stands() -> None:
    from amrst.plot.stemmap import which_way_up

    xyz = scan((0.5, 0.5), STEMS, 3)
    assert which_way_up(map_stems(xyz, trees=False)) == ""
    y_up = xyz[:, [0, 2, 1]] * [1.0, 1.0, -1.0]  # the file's y is the height
    assert which_way_up(map_stems(y_up, trees=False)) == "with its y axis up"
    upside_down = xyz * [1.0, -1.0, -1.0]
    assert which_way_up(map_stems(upside_down, trees=False)) == "upside down"


def test_a_sparse_stem_hidden_in_its_own_bush_is_a_tree() -> None:
    # A 6 m tree seen from one side by a few points a centimetre: its foliage hides
    # the lowest 1.9 m, the stem shows from there to its crown at 2.8 m.
    z0 = float(ground_z(np.zeros(2)))
    rng = np.random.default_rng(21)
    a = rng.uniform(-np.pi / 2, np.pi / 2, 110)
    z = rng.uniform(z0 + 1.9, z0 + 2.8, 110)
    stem = np.column_stack([0.085 * np.cos(a), 0.085 * np.sin(a), z])
    bush = blob((0.0, 0.0, z0 + 1.1), 0.6, 4000, 22)
    bush = bush[bush[:, 2] > z0 + 0.3]
    crown = blob((0.0, 0.0, z0 + 4.4), 1.6, 6000, 23)
    crown = crown[crown[:, 2] > z0 + 2.8]
    xyz = np.vstack([_ground(), stem, bush, crown])
    inv = take_inventory([Cloud(xyz)], [np.eye(4)])
    assert len(inv.trees) == 1
    assert np.hypot(*inv.trees[0].xyz[:2]) < 0.15
    assert inv.trees[0].stem.height_m == pytest.approx(6.0, abs=0.3)


def test_a_plot_scan_keeps_no_neighbour_lists_for_later_stages(
    plot_pair, plot_scans
) -> None:
    # A plot scan gets no wood-leaf separation nor skeleton: nothing reads the
    # neighbours its outlier filter listed; a two-scan analysis keeps them.
    from amrst.params import RegistrationParams
    from amrst.pipeline import prepare_scan

    _, scans = plot_scans
    assert all(s.analysis.pre.neighbours is None for s in scans)
    pair = prepare_scan(plot_pair[0], RegistrationParams())
    assert pair.pre.neighbours is not None
    assert pair.pre.neighbours.k > RegistrationParams().preprocess.outlier_neighbours
