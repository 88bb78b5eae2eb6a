"""Several scans of one tree: links, spanning tree, joint refinement, export, CLI."""

from __future__ import annotations

import json
from dataclasses import replace

import numpy as np
import pytest
from _graphs import link

import amrst
from amrst import io
from amrst.cli import main
from amrst.multiscan.export import export_scans, read_scan_truth
from amrst.multiscan.graph import (
    loop_closures,
    loop_confirmed,
    scan_statuses,
    spanning_tree,
)
from amrst.multiscan.simulate import simulate_scans, write_scans
from amrst.stages.metrics import truth_errors


@pytest.fixture(scope="module")
def three_scans(tiny_tree):
    """Three simulated scans of the tiny tree, 60-120 deg apart, with their truth."""
    return simulate_scans(tiny_tree, 3, seed=0, res_deg=0.2)


@pytest.fixture(scope="module")
def three_result(three_scans):
    return amrst.register_scans(three_scans.scans, reference=0)


def test_two_scans_give_the_pair_result_exactly(sample_pair, sample_run):
    result = amrst.register_scans([sample_pair.target, sample_pair.source])
    pair = sample_run.result
    assert np.array_equal(result.T_reference_scan[1], pair.T_target_source)
    assert np.array_equal(result.T_reference_scan[0], np.eye(4))
    assert result.pair is not None
    assert result.pair.metrics_fine == pair.metrics_fine
    (link,) = result.links
    assert (link.target, link.source, link.in_tree) == (0, 1, True)
    assert link.verified
    assert link.status == result.status == "registered"
    assert result.paths == ((0,), (0, 1))


def test_a_set_whose_tree_link_did_not_converge_needs_review(three_result):
    assert three_result.status == "registered"
    stopped = tuple(
        replace(ln, fine_converged=False) if ln.in_tree and ln.source == 2 else ln
        for ln in three_result.links
    )
    assert replace(three_result, links=stopped).status == "needs review"


def test_reference_other_than_first(sample_pair, sample_run):
    result = amrst.register_scans([sample_pair.source, sample_pair.target], reference=1)
    assert np.array_equal(result.T_reference_scan[0], sample_run.result.T_target_source)


def test_three_scans_all_placed_within_truth(three_scans, three_result):
    truth = three_scans.T_reference_scan(0)
    assert three_result.status == "registered"
    assert len(three_result.links) == 3
    assert all(link.verified for link in three_result.links)
    for k in range(3):
        err = truth_errors(
            three_result.T_reference_scan[k], truth[k], three_scans.scans[k].xyz
        )
        assert err.rotation_error_deg < 1.0
        assert err.translation_error_m < 0.05
        path = three_result.paths[k]
        assert path is not None
        assert path[0] == 0
        assert path[-1] == k
    tree_links = [link for link in three_result.links if link.in_tree]
    assert len(tree_links) == 2  # a spanning tree of 3 scans
    # the joint refinement moved the scans and made the worst one better, not worse
    joint = three_result.joint
    assert joint is not None
    assert joint.kept
    assert max(joint.moved_m) > 1e-4
    assert joint.rmse_after_m <= joint.rmse_before_m

    def worst(poses):
        return max(
            truth_errors(poses[k], truth[k], three_scans.scans[k].xyz).gt_rmse_m
            for k in range(3)
        )

    assert worst(three_result.T_reference_scan) <= worst(three_result.T_tree)


def test_scan_unverified_with_reference_reached_through_another():
    links = [
        link(0, 1, "verified", 0.6),
        link(0, 2, "unverified", 0.9),
        link(1, 2, "verified", 0.4),
        link(0, 3, "failed", 0.0),
        link(1, 3, "unverified", 0.5),
        link(2, 3, "unverified", 0.5),
    ]
    graph = spanning_tree(links, 4, 0)
    assert graph.paths[:3] == ((0,), (0, 1), (0, 1, 2))
    assert graph.paths[3] is None
    assert graph.poses[3] is None
    np.testing.assert_allclose(
        graph.poses[2][:3, 3], [2.0, 0.0, 0.0]
    )  # 0->1->2 composed
    assert [link.in_tree for link in graph.links] == [
        True,
        False,
        True,
        False,
        False,
        False,
    ]


def test_direct_verified_link_is_preferred_to_a_better_detour():
    links = [
        link(0, 1, "verified", 0.2),
        link(0, 2, "verified", 0.9),
        link(1, 2, "verified", 0.9),
    ]
    assert spanning_tree(links, 3, 0).paths[1] == (0, 1)


def test_export_many_scans(tmp_path, three_scans, three_result):
    truth = three_scans.T_reference_scan(0)
    files = export_scans(tmp_path / "out", three_result, truth=truth, clouds=True)
    names = {f.name for f in files}
    assert {
        "transform.json",
        "transform_2.txt",
        "metrics.json",
        "merged.ply",
        "scans.json",
    } <= names
    doc = json.loads((tmp_path / "out" / "scans.json").read_text())
    assert doc["status"] == "registered"
    assert "verdict" not in doc
    assert {(d["status"], d["verified"]) for d in doc["links"]} == {
        ("registered", True)
    }
    assert doc["links_total"] == 3
    assert all(s["truth"]["registered"] for s in doc["scans"])
    merged = io.read(tmp_path / "out" / "merged.ply")
    assert np.bincount(merged.attributes["scan_id"]).tolist() == [
        len(s) for s in three_scans.scans
    ]
    T2 = np.loadtxt(tmp_path / "out" / "transform_2.txt")
    np.testing.assert_allclose(T2, three_result.T_reference_scan[2], atol=1e-9)
    export_scans(tmp_path / "out", three_result)  # no clouds: the earlier one goes
    assert not (tmp_path / "out" / "merged.ply").exists()
    assert (tmp_path / "out" / "scans.json").is_file()


def test_cli_three_scans_and_truth(tmp_path, three_scans, capsys):
    folder = write_scans(three_scans, tmp_path / "tree", "tiny", 0)
    truth = read_scan_truth(folder / "truth.json", 3, 0)
    np.testing.assert_allclose(truth[2], three_scans.T_reference_scan(0)[2])
    scans = [str(folder / f"scan_{k}.ply") for k in range(3)]
    code = main(
        [
            "register",
            *scans,
            "--out",
            str(tmp_path / "out"),
            "--truth",
            str(folder / "truth.json"),
            "--quiet",
        ]
    )
    out = capsys.readouterr().out
    assert code == 0, out
    assert "scan 2" in out
    assert "link 1-2" in out
    doc = json.loads((tmp_path / "out" / "scans.json").read_text())
    assert doc["scans"][1]["file"] == scans[1]


def test_campaign_simulate_never_writes_over_a_folder(
    tmp_path, tiny_tree_path, three_scans, capsys
):
    from amrst.errors import InvalidInput

    out = tmp_path / "tree"
    argv = ["campaign", "simulate", str(tiny_tree_path), "--out", str(out)]
    assert main([*argv, "--scans", "3", "--res-deg", "0.2"]) == 0
    assert sorted(p.name for p in out.iterdir()) == [
        "scan_0.ply",
        "scan_1.ply",
        "scan_2.ply",
        "truth.json",
    ]
    before = {p.name: p.read_bytes() for p in out.iterdir()}
    # Fewer scans into the same folder: refused, no stale scan_2 beside a new truth.
    capsys.readouterr()
    assert main([*argv, "--scans", "2", "--res-deg", "0.3"]) == 2
    err = capsys.readouterr().err
    assert "already holds files" in err
    assert err.count("\n") == 1
    assert {p.name: p.read_bytes() for p in out.iterdir()} == before
    # A folder holding other files is refused too, and by the library.
    other = tmp_path / "other"
    other.mkdir()
    (other / "notes.txt").write_text("x")
    with pytest.raises(InvalidInput, match="already holds files"):
        write_scans(three_scans, other)
    assert [p.name for p in other.iterdir()] == ["notes.txt"]


def test_cli_e57_scan_specs(tmp_path, three_scans, capsys):
    from _writers import write_e57

    write_e57(tmp_path / "plot.e57", three_scans.scans)
    plot = tmp_path / "plot.e57"
    code = main(
        [
            "register",
            f"{plot}#0",
            f"{plot}#1",
            f"{plot}#2",
            "--out",
            str(tmp_path / "o"),
            "--quiet",
        ]
    )
    assert code == 0, capsys.readouterr()
    code = main(["register", f"{plot}#0", f"{plot}#7", "--out", str(tmp_path / "o2")])
    err = capsys.readouterr().err
    assert code == 2
    assert "no scan 7" in err
    # Options of a pair of files are refused, not silently left unused.
    pair_only = ["--pairs", "p.csv", "--stem", "1", "2"]
    code = main(["register", str(plot), "--out", str(tmp_path / "o6"), *pair_only])
    assert code == 2
    assert "--pairs and --stem work on two scan files" in capsys.readouterr().err
    assert not (tmp_path / "o6").exists()
    # The file alone gives its three scans; with another scan, its two and that one
    # (never its scans as one cloud, unposed).
    assert main(["register", str(plot), "--out", str(tmp_path / "o3"), "--quiet"]) == 0
    assert json.loads((tmp_path / "o3" / "scans.json").read_text())["n_scans"] == 3
    write_e57(tmp_path / "two.e57", three_scans.scans[:2])
    io.write(tmp_path / "c.ply", three_scans.scans[2])
    args = [str(tmp_path / "two.e57"), str(tmp_path / "c.ply")]
    assert main(["register", *args, "--out", str(tmp_path / "o4"), "--quiet"]) == 0
    assert json.loads((tmp_path / "o4" / "scans.json").read_text())["n_scans"] == 3
    assert (
        main(["register", str(tmp_path / "c.ply"), "--out", str(tmp_path / "o5")]) == 2
    )
    assert "Two scans or more are needed" in capsys.readouterr().err


def test_unsure_direct_link_gives_way_to_registered_detour():
    # 0-2 verified but its runner-up scored almost as well (low confidence): the
    # scan goes through 1, whose two links are sure, and the unsure link is left out.
    links = [
        link(0, 1, "verified", 0.3),
        link(0, 2, "verified", 0.9, confidence=0.05, shift=-40.0),
        link(1, 2, "verified", 0.2),
    ]
    graph = spanning_tree(links, 3, 0)
    assert graph.paths[2] == (0, 1, 2)
    loops = loop_closures(graph.links, graph.poses)
    assert loops["0-2"] > 1.0  # the unsure link disagrees, and says nothing
    assert scan_statuses(graph.links, graph.paths, loops) == ("registered",) * 3


def test_unsure_link_on_the_only_path_needs_review():
    links = [link(0, 1, "verified", 0.3, confidence=0.05), link(0, 2, "failed", 0.0)]
    graph = spanning_tree(links, 3, 0)
    statuses = scan_statuses(graph.links, graph.paths, {})
    assert statuses == ("registered", "needs review", "failed")


def test_registered_links_that_disagree_flag_the_scans_behind_them():
    links = [
        link(0, 1, "verified", 0.5),
        link(1, 2, "verified", 0.5),
        link(0, 2, "verified", 0.1, shift=3.0),  # sure, and 1 m off the tree
        link(0, 3, "verified", 0.5),
    ]
    graph = spanning_tree(links, 4, 0)
    assert graph.paths[2] == (0, 2)
    # The tree joins 2 directly; the left-out 1-2 puts it 1 m elsewhere.
    loops = loop_closures(graph.links, graph.poses)
    assert loops["1-2"] == pytest.approx(1.0)
    assert scan_statuses(graph.links, graph.paths, loops) == (
        "registered",
        "needs review",
        "needs review",
        "registered",
    )


def test_a_loop_that_closes_confirms_its_unsure_links():
    # Three scans, every link verified but unsure (a runner-up close behind): the
    # cycle 0-1-2 closes exactly, so no link of it can be wrong.
    links = [
        link(0, 1, "verified", 0.5, confidence=0.1),
        link(1, 2, "verified", 0.5, confidence=0.1),
        link(0, 2, "verified", 0.4, confidence=0.1),
        link(0, 3, "verified", 0.5, confidence=0.1),  # no loop through scan 3
    ]
    graph = spanning_tree(links, 4, 0)
    loops = loop_closures(graph.links, graph.poses)
    assert max(loops.values()) < 1e-9
    pairs = {frozenset(p) for p in ((0, 1), (1, 2), (0, 2))}
    assert loop_confirmed(graph.links, graph.paths, loops) == pairs
    assert scan_statuses(graph.links, graph.paths, loops) == (
        "registered",
        "registered",
        "registered",
        "needs review",
    )
    # 10 cm off at 10 m: no longer confirmed, nor contradicted.
    links[2] = link(0, 2, "verified", 0.4, confidence=0.1, shift=2.1)
    graph = spanning_tree(links, 4, 0)
    loops = loop_closures(graph.links, graph.poses)
    assert list(loops.values()) == [pytest.approx(0.1)]
    assert scan_statuses(graph.links, graph.paths, loops) == (
        "registered",
        "needs review",
        "needs review",
        "needs review",
    )


def test_cli_names_the_scans_no_verified_link_reaches(tmp_path, sample_pair, capsys):
    from amrst.types import Cloud

    rng = np.random.default_rng(0)
    box = tmp_path / "box.ply"
    io.write(box, Cloud(rng.uniform(-3, 3, (3000, 3))))
    t, s = str(sample_pair.target_path), str(sample_pair.source_path)
    code = main(["register", t, s, str(box), "--out", str(tmp_path / "o"), "--quiet"])
    assert code == 3
    err = capsys.readouterr().err
    assert f"no verified link reaches some scans: {box}." in err


def test_scans_of_a_plot_are_said_to_be_one_and_point_to_amrst_plot(three_result):
    import dataclasses

    from amrst.multiscan.cli import describe

    labels = ["a.ply", "b.ply", "c.ply"]
    assert three_result.stems  # the scene stage's stems, counted per scan
    lines = describe(dataclasses.replace(three_result, stems=(9, 11, 10)), labels)
    text = "\n".join(lines)
    assert "the scans hold 9, 11, 10 stems: a plot, not one tree" in text
    assert "amrst plot a.ply b.ply c.ply --out DIR" in text
    assert "tree (merged)" not in text  # a plot is never described as one tree
    one = "\n".join(
        describe(dataclasses.replace(three_result, stems=(1, 1, 1)), labels)
    )
    assert "a plot" not in one
    assert "tree (merged)" in one


def test_cli_scans_do_not_replace_what_another_run_wrote_meanwhile(
    tmp_path, three_scans, capsys, monkeypatch
):
    from _writers import written_first

    from amrst.multiscan import register as multiscan_register

    files = [tmp_path / f"s{k}.ply" for k in range(3)]
    for f, scan in zip(files, three_scans.scans, strict=True):
        io.write(f, scan)
    out = tmp_path / "o"
    registered = multiscan_register.register_scans
    another_run = written_first(registered, out / "scans.json", "{}")
    monkeypatch.setattr(multiscan_register, "register_scans", another_run)
    assert main(["register", *map(str, files), "--out", str(out), "--quiet"]) == 2
    assert "changed while this run worked" in capsys.readouterr().err
    assert (out / "scans.json").read_text() == "{}"
    assert not (out / "transform.json").exists()
