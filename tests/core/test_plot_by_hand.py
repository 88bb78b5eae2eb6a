"""A plot link placed from point pairs the technician picked (``amrst plot --pairs``)."""

from __future__ import annotations

import json
import os
import shutil
from typing import TYPE_CHECKING

import numpy as np
import pytest
from _plots import STEMS, ground_z, plot_pair, pose, scan

from amrst import io
from amrst.plot.cli import main as plot_main
from amrst.plot.register import HAND_ORIGIN, analyse_plot, register_plot
from amrst.review.pairs_file import write_pairs
from amrst.types import (
    Cloud,
    invert_transform,
    rotation_angle_deg,
    world_transform,
)

if TYPE_CHECKING:
    from pathlib import Path


@pytest.fixture(scope="module")
def pair_and_picks() -> tuple[list[Cloud], np.ndarray, np.ndarray, np.ndarray]:
    """The plot pair with world offsets, four stem points picked in each scan (1 cm
    pick error, world coordinates), and the true pose between the local frames."""
    target, source, T_true = plot_pair()
    picked = np.array(
        [(x, y, float(ground_z(np.array([x, y]))) + 1.0) for x, y, *_ in STEMS[:4]]
    )
    in_source = (
        picked @ invert_transform(T_true)[:3, :3].T + invert_transform(T_true)[:3, 3]
    )
    rng = np.random.default_rng(5)
    in_source += rng.normal(0.0, 0.01, in_source.shape)
    # Georeferenced files: the pairs are picked in world coordinates.
    offsets = np.array(
        [[512_000.0, 4_200_000.0, 300.0], [512_004.0, 4_200_001.0, 300.5]]
    )
    clouds = [
        Cloud(target, offset=offsets[0], name="t"),
        Cloud(source, offset=offsets[1], name="s"),
    ]
    return clouds, picked + offsets[0], in_source + offsets[1], T_true


def test_point_pairs_place_the_link(pair_and_picks) -> None:
    clouds, t_pts, s_pts, T_true = pair_and_picks
    reg = register_plot(analyse_plot(clouds), by_hand={(0, 1): (t_pts, s_pts)})
    link = reg.links[0].link
    assert link.origin == HAND_ORIGIN
    assert link.status == "registered", link.message
    assert "point pairs" in link.message
    E = invert_transform(T_true) @ reg.poses[1]
    assert rotation_angle_deg(E[:3, :3]) < 0.2
    assert np.linalg.norm(E[:3, 3]) < 0.02
    assert reg.statuses == ("registered", "registered")
    # The same pairs named the other way round (scan 2's points first) agree.
    again = register_plot(analyse_plot(clouds), by_hand={(1, 0): (s_pts, t_pts)})
    assert np.allclose(again.poses[1], reg.poses[1], atol=1e-6)


def test_pairs_of_the_wrong_points_are_never_called_registered(pair_and_picks) -> None:
    from amrst.errors import InvalidInput

    clouds, t_pts, s_pts, _ = pair_and_picks
    off = np.add(s_pts, (0.4, 0.0, 0.0))  # every pick 40 cm beside its stem
    scans = analyse_plot(clouds)
    reg = register_plot(scans, by_hand={(0, 1): (t_pts, off)})
    assert reg.links[0].link.origin == HAND_ORIGIN
    assert reg.statuses[1] == "needs review"
    # The file's columns swapped: each scan's points given as the other's.
    turned = register_plot(scans, by_hand={(0, 1): (s_pts, t_pts)})
    assert turned.statuses[1] == "needs review"
    message = turned.links[0].link.message
    assert "target and source columns are swapped" in message
    assert "--pairs 2 1" in message
    assert "swapped" not in reg.links[0].link.message  # the picks 40 cm off
    swapped = s_pts[[1, 2, 3, 0]]  # every pick on another stem: no pose follows
    with pytest.raises(InvalidInput, match="same point in both scans"):
        register_plot(scans, by_hand={(0, 1): (t_pts, swapped)})


def test_the_command_reads_pairs_and_refuses_bad_ones(
    pair_and_picks, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    clouds, t_pts, s_pts, T_true = pair_and_picks
    scans = _files(clouds, tmp_path)
    pairs = tmp_path / "pairs.csv"
    write_pairs(pairs, t_pts, s_pts)
    out = tmp_path / "out"
    assert (
        plot_main(
            [*scans, "--out", str(out), "--quiet", "--pairs", "1", "2", str(pairs)]
        )
        == 0
    )
    doc = json.loads((out / "plot.json").read_text())
    assert doc["links"][0]["origin"] == HAND_ORIGIN
    # The pose handed over moves the source file's coordinates onto the target's.
    T_file = np.array(doc["scans"][1]["T_reference_scan"])
    T_world = world_transform(T_true, clouds[0], clouds[1])
    at = clouds[1].xyz[::500] + clouds[1].offset
    assert (
        np.abs(at @ T_file[:3, :3].T + T_file[:3, 3] - _moved(T_world, at)).max() < 0.01
    )
    # The columns of the file swapped: the command says so, and how to give it.
    turned = tmp_path / "turned.csv"
    write_pairs(turned, s_pts, t_pts)
    capsys.readouterr()
    args = [*scans, "--out", str(tmp_path / "turned"), "--quiet", "--pairs", "1", "2"]
    assert plot_main([*args, str(turned)]) == 3
    err = capsys.readouterr().err
    assert "link 1-2, from your point pairs, needs review: " in err
    assert "columns are swapped (give it as --pairs 2 1)" in err
    huge = tmp_path / "huge.csv"  # one field over the csv module's limit
    huge.write_text(
        "target_x,target_y,target_z,source_x,source_y,source_z\n" + "1" * 200_000
    )
    swapped = tmp_path / "swapped.csv"  # the rows of one scan in another order
    write_pairs(swapped, t_pts, s_pts[[1, 2, 3, 0]])
    fifo = tmp_path / "fifo.csv"
    os.mkfifo(fifo)
    capsys.readouterr()  # what the runs before said
    for bad, why in (
        (["1", "2", str(swapped)], "same point in both scans"),
        (["1", "3", str(pairs)], "the plot has scans 1 to 2"),
        (["0", "2", str(pairs)], "numbers from 1"),
        (["1", "²", str(pairs)], "numbers from 1"),  # a digit, but no number
        (["1", "2", str(tmp_path / "no.csv")], "The pairs file"),
        (["1", "2", str(fifo)], "named pipe"),  # reading it would wait forever
        (["1", "2", str(huge)], "is not a pairs CSV"),
    ):
        args = [*scans, "--out", str(tmp_path / "bad"), "--quiet", "--pairs", *bad]
        assert plot_main(args) == 2
        err = capsys.readouterr().err
        assert why in err
        assert len(err.strip().splitlines()) == 1


def test_a_link_the_technician_accepted_clears_its_scan_at_that_pose_only(
    pair_and_picks, tmp_path: Path, capsys
) -> None:
    from amrst.plot.review import PlotReview, write_review

    clouds, t_pts, s_pts, _ = pair_and_picks
    wrong = tmp_path / "wrong.csv"
    write_pairs(wrong, t_pts, np.add(s_pts, (0.4, 0.0, 0.0)))  # 40 cm off: review
    out = tmp_path / "out"
    scans = _files(clouds, tmp_path)
    args = [*scans, "--out", str(out), "--quiet", "--pairs", "1", "2"]
    assert plot_main([*args, str(wrong), "--report"]) == 3
    doc = json.loads((out / "plot.json").read_text())
    labels = [s["label"] for s in doc["scans"]]
    T = np.array(doc["scans"][1]["T_reference_scan"])  # the pose to accept
    assert [s["state"] for s in doc["scans"]] == ["registered", "needs review"]
    # Every tree scan 2 sees rests on its unsure pose, and trees.csv says so.
    rows = _tree_rows(out)
    assert any("2" in r["seen_from"].split(";") for r in rows)
    for r in rows:
        assert r["scans_to_check"] == ("2" if "2" in r["seen_from"].split(";") else "")
    page = (out / "report.html").read_text()
    resting = sum(1 for r in rows if r["scans_to_check"])
    assert f"{resting} tree{'s' if resting > 1 else ''} seen from a scan that" in page
    assert "(check 2)" in page

    write_review(out, labels, PlotReview(accepted={(0, 1): T}))
    assert plot_main([*args, str(wrong), "--overwrite"]) == 0
    doc = json.loads((out / "plot.json").read_text())
    assert [s["status"] for s in doc["scans"]] == ["registered", "needs review"]
    assert [s["state"] for s in doc["scans"]] == ["registered", "accepted"]
    assert doc["links"][0]["accepted"]
    assert all(r["scans_to_check"] == "" for r in _tree_rows(out))

    # The same from the command line: --accept takes the pose the last run gave,
    # the one checked, and a later run without it keeps the acceptance.
    (out / "review.json").unlink()
    assert plot_main([*args, str(wrong), "--overwrite", "--accept", "2", "1"]) == 0
    doc = json.loads((out / "plot.json").read_text())
    assert [s["state"] for s in doc["scans"]] == ["registered", "accepted"]
    review = json.loads((out / "review.json").read_text())
    np.testing.assert_allclose(review["accepted"]["1-2"], T, atol=1e-9)
    stamp = (out / "review.json").stat().st_mtime_ns
    assert plot_main([*args, str(wrong), "--overwrite", "--accept", "1", "2"]) == 0
    assert (out / "review.json").stat().st_mtime_ns == stamp  # nothing new to keep
    assert plot_main([*args, str(wrong), "--overwrite"]) == 0
    doc = json.loads((out / "plot.json").read_text())
    assert [s["state"] for s in doc["scans"]] == ["registered", "accepted"]
    # The same scans copied elsewhere are the scans of that run: --accept holds.
    (out / "review.json").unlink()
    (tmp_path / "moved").mkdir()
    moved = [shutil.copy(f, tmp_path / "moved") for f in scans]
    again = [*moved, *args[len(scans) :], str(wrong), "--overwrite"]
    assert plot_main([*again, "--accept", "1", "2"]) == 0
    doc = json.loads((out / "plot.json").read_text())
    assert [s["state"] for s in doc["scans"]] == ["registered", "accepted"]
    capsys.readouterr()
    accept = ["--accept", "1", "2", "--quiet"]
    for bad, why in (
        (
            [*scans, "--out", str(out), "--overwrite", "--leave-out", "1", "2"],
            "left out",
        ),
        ([*scans, "--out", str(tmp_path / "new")], "run the plot first"),
    ):
        assert plot_main([*bad, *accept]) == 2
        assert why in capsys.readouterr().err

    # The right pairs move the link: the acceptance of the other pose no longer holds
    # (the link is registered on its own).
    right = tmp_path / "right.csv"
    write_pairs(right, t_pts, s_pts)
    assert plot_main([*args, str(right), "--overwrite"]) == 0
    doc = json.loads((out / "plot.json").read_text())
    assert [s["state"] for s in doc["scans"]] == ["registered", "registered"]
    assert not doc["links"][0]["accepted"]
    # A link that needs no review has nothing to accept, and the run says so.
    capsys.readouterr()
    assert plot_main([*args, str(right), "--overwrite", "--accept", "1", "2"]) == 0
    assert "scans 1 and 2 is registered: nothing to accept" in capsys.readouterr().err
    for bad, why in (
        (["1", "1"], "named twice"),
        (["1", "3"], "scans 1 to 2"),
        (["3", "3"], "Scan 3 named for a link does not exist"),
    ):
        assert plot_main([*args, str(right), "--overwrite", "--accept", *bad]) == 2
        assert why in capsys.readouterr().err


def test_a_link_left_out_is_not_registered_and_the_scan_joins_through_another(
    tmp_path: Path,
) -> None:
    from amrst.errors import InvalidInput
    from amrst.plot.register import LEFT_OUT_ORIGIN

    target, source, T_source = plot_pair()
    T_third = pose(-40.0, (0.5, -6.0, 0.0))
    world = scan((0.5, -6.0), STEMS, 3, hidden_tops=True)
    inv = invert_transform(T_third)
    third = world @ inv[:3, :3].T + inv[:3, 3]
    clouds = [Cloud(c) for c in (target, source, third)]
    scans = analyse_plot(clouds)
    reg = register_plot(scans, left_out=[(2, 0)])  # either order
    by_pair = {(pl.link.target, pl.link.source): pl.link for pl in reg.links}
    assert by_pair[0, 2].origin == LEFT_OUT_ORIGIN
    assert by_pair[0, 2].status == "failed"
    assert reg.paths[2] == (0, 1, 2)
    assert reg.poses[2] is not None  # placed, as sure as the 2-3 link alone
    # Three scans: a joint refinement, judged by the bundle error the plot reports.
    assert reg.joint is not None
    judged = reg.joint.rmse_after_m if reg.joint.kept else reg.joint.rmse_before_m
    assert judged == pytest.approx(reg.bundle_rmse_m)
    for T_true, T in ((T_source, reg.poses[1]), (T_third, reg.poses[2])):
        err = invert_transform(T_true) @ T
        assert rotation_angle_deg(err[:3, :3]) < 0.1
        assert np.linalg.norm(err[:3, 3]) < 0.02

    picks = np.zeros((3, 3)), np.eye(3)
    with pytest.raises(InvalidInput, match="both given point pairs and left out"):
        register_plot(scans, by_hand={(0, 2): picks}, left_out=[(0, 2)])
    with pytest.raises(InvalidInput, match="Scan 4 named for a link does not exist"):
        register_plot(scans, left_out=[(0, 3)])
    with pytest.raises(InvalidInput, match="Scan 2 named twice for a link"):
        register_plot(scans, left_out=[(1, 1)])
    args = [*_files(clouds, tmp_path), "--out", str(tmp_path / "o"), "--quiet"]
    assert plot_main([*args, "--leave-out", "1", "x"]) == 2
    assert plot_main([*args, "--leave-out", "1", "3"]) == 0  # 2-3 holds alone
    doc = json.loads((tmp_path / "o" / "plot.json").read_text())
    assert [ln["origin"] for ln in doc["links"] if ln["target"] == 0][1] == "left out"
    assert [s["state"] for s in doc["scans"]] == ["registered"] * 3


def _moved(T: np.ndarray, xyz: np.ndarray) -> np.ndarray:
    return xyz @ T[:3, :3].T + T[:3, 3]


def _files(clouds: list[Cloud], folder: Path) -> list[str]:
    """Write the scans as s1.ply, s2.ply, ... in ``folder``; return their paths."""
    files = [folder / f"s{k + 1}.ply" for k in range(len(clouds))]
    for f, c in zip(files, clouds, strict=True):
        io.write(f, c)
    return [str(f) for f in files]


def _tree_rows(out: Path) -> list[dict[str, str]]:
    import csv

    with (out / "trees.csv").open() as fh:
        return list(csv.DictReader(fh))


def test_the_scans_links_left_out_cut_off_are_told() -> None:
    from amrst.plot.register import cut_off

    # Every scan keeps a link, but 3 and 4 only to each other.
    cut = [(0, 2), (0, 3), (1, 2), (1, 3)]
    assert cut_off(4, 0, cut) == {2, 3}
    assert cut_off(4, 0, cut[:3]) == set()  # 2-4 joins them
    assert cut_off(2, 0, [(1, 0)]) == {1}
