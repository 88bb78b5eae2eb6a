"""A plot's review: marks, DBHs by hand and accepted links in review.json, and the
states they give."""

from __future__ import annotations

import json
import os

import numpy as np
import pytest
from _graphs import link

from amrst.errors import InvalidInput
from amrst.multiscan.graph import loop_closures, scan_doubts, spanning_tree
from amrst.plot.review import (
    ACCEPTED,
    REVIEW_JSON,
    HandCircle,
    PlotReview,
    hand_circle,
    read_review,
    scan_state,
    still_holds,
    write_review,
)
from amrst.types import invert_transform, make_transform

LABELS = ["/plots/a.ply", "/plots/b.ply"]


def _turned(deg: float, shift: float = 0.0) -> np.ndarray:
    a = np.radians(deg)
    R = np.array([[np.cos(a), -np.sin(a), 0], [np.sin(a), np.cos(a), 0], [0, 0, 1]])
    return make_transform(R, np.array([3.0 + shift, -1.0, 0.2]))


def test_the_review_is_written_and_read_back(tmp_path):
    review = PlotReview(
        {"T003": "check", "T001": "ok", "T004": "not a tree"},
        {(0, 1): _turned(30.0)},
        {"T002": HandCircle((4.5, -2.25), 0.315)},
        added={"H001": (1.5, -3.25), "H004": (0.0, 7.0)},
    )
    write_review(tmp_path, LABELS, review)
    back = read_review(tmp_path, LABELS)
    assert back.marks == review.marks
    assert back.dbh == review.dbh
    assert back.added == review.added
    assert list(back.accepted) == [(0, 1)]
    assert np.array_equal(back.accepted[0, 1], _turned(30.0))
    doc = json.loads((tmp_path / REVIEW_JSON).read_text())
    assert list(doc["accepted"]) == ["1-2"]  # scans numbered as the user sees them


def test_a_review_of_other_scans_is_not_applied(tmp_path):
    write_review(tmp_path, LABELS, PlotReview({"T001": "ok"}, {(0, 1): np.eye(4)}))
    assert read_review(tmp_path, ["/plots/c.ply", "/plots/b.ply"]) == PlotReview()
    assert read_review(tmp_path, LABELS[::-1]) == PlotReview()  # another reference
    assert read_review(tmp_path / "none", LABELS) == PlotReview()


def test_a_review_holds_with_scans_removed_or_added_around_its_reference(tmp_path):
    a, b, c, d = (f"/plots/{n}.ply" for n in "abcd")
    review = PlotReview(
        {"T001": "ok", "T002": "check"},
        {(0, 1): _turned(10.0), (1, 2): _turned(20.0), (0, 2): _turned(30.0)},
        {"T002": HandCircle((4.5, -2.25), 0.315)},
        added={"H001": (1.5, -3.25)},
        at={"T001": (1.0, 2.0), "T002": (4.5, -2.25)},
    )
    write_review(tmp_path, [a, b, c], review)
    # b removed: the trees' review holds; a-c is now link (0, 1); links of b go.
    held = read_review(tmp_path, [a, c])
    assert (held.marks, held.dbh, held.added, held.at) == (
        review.marks,
        review.dbh,
        review.added,
        review.at,
    )
    assert list(held.accepted) == [(0, 1)]
    assert np.array_equal(held.accepted[0, 1], _turned(30.0))
    # d added between: every link keeps its two scans.
    held = read_review(tmp_path, [a, d, b, c])
    assert sorted(held.accepted) == [(0, 2), (0, 3), (2, 3)]
    assert np.array_equal(held.accepted[2, 3], _turned(20.0))
    # b and c swapped: their link is (1, 2) again, its pose the other way round.
    held = read_review(tmp_path, [a, c, b])
    assert sorted(held.accepted) == [(0, 1), (0, 2), (1, 2)]
    assert np.allclose(held.accepted[1, 2], invert_transform(_turned(20.0)))


@pytest.mark.parametrize(
    "doc",
    [
        "not json",
        {"scans": LABELS, "marks": {"T001": "great"}},
        {"scans": LABELS, "marks": {}, "accepted": {"1-2": [[1, 0], [0, 1]]}},
        {"scans": LABELS, "marks": {}, "accepted": {"0-2": np.eye(4).tolist()}},
        {"scans": LABELS, "marks": {}, "dbh": {"T001": {"x_m": 0, "y_m": 0}}},
        {"scans": LABELS, "marks": {}, "added": [{"x_m": 1.0}]},
        {"scans": LABELS, "marks": {}, "added": [{"x_m": "nan", "y_m": 0}]},
        {"scans": LABELS, "marks": {}, "added": [{"x_m": 1, "y_m": 1e400}]},
        {"scans": LABELS, "marks": {}, "added": [{"x_m": 10**400, "y_m": 0}]},
        {
            "scans": LABELS,
            "marks": {},
            "added": [
                {"id": "H1", "x_m": 0, "y_m": 0},
                {"id": "H1", "x_m": 1, "y_m": 1},
            ],
        },
        {
            "scans": LABELS,
            "marks": {},
            "dbh": {"T001": {"x_m": 0, "y_m": 0, "dbh_m": -1}},
        },
    ],
)
def test_a_broken_review_is_refused_in_one_line(tmp_path, doc):
    text = doc if isinstance(doc, str) else json.dumps(doc)
    (tmp_path / REVIEW_JSON).write_text(text)
    with pytest.raises(InvalidInput) as err:
        read_review(tmp_path, LABELS)
    assert "\n" not in str(err.value)
    assert REVIEW_JSON in str(err.value)


def test_a_bad_mark_is_not_written(tmp_path):
    with pytest.raises(InvalidInput):
        write_review(tmp_path, LABELS, PlotReview({"T001": "maybe"}))
    assert not (tmp_path / REVIEW_JSON).exists()


def test_an_acceptance_holds_for_its_pose_only():
    accepted, near = _turned(30.0), np.array([5.0, 3.0, 1.0])
    assert still_holds(accepted, _turned(30.0 + 0.01, 0.002), near)
    assert not still_holds(accepted, _turned(30.2), near)
    assert not still_holds(accepted, _turned(30.0, 0.03), near)
    assert not still_holds(accepted, None, near)


def test_an_acceptance_of_georeferenced_scans_is_judged_where_they_are():
    # The same turn by 0.001 deg about the scans moves them 0.2 mm, but the origin of
    # the frame (4,200 km away) by metres: judged at the scans, it holds.
    at = np.array([512_004.0, 4_200_001.0, 300.5])
    T = make_transform(np.eye(3), [-4.0, -1.0, -0.5])
    a = np.radians(0.001)
    R = np.array([[np.cos(a), -np.sin(a), 0], [np.sin(a), np.cos(a), 0], [0, 0, 1]])
    about_at = make_transform(R, at - R @ at)  # a turn about the point ``at``
    assert still_holds(T, T @ about_at, at)
    assert np.linalg.norm((T @ about_at)[:3, 3] - T[:3, 3]) > 0.01


def test_a_scan_reads_accepted_when_each_unsure_link_it_rests_on_is():
    # Scan 2 hangs on two unsure links (0-1, 1-2); scan 3's link failed.
    links = [
        link(0, 1, "verified", 0.5, confidence=0.1),
        link(1, 2, "verified", 0.5, confidence=0.1),
        link(0, 3, "failed", 0.0),
    ]
    graph = spanning_tree(links, 4, 0)
    loops = loop_closures(graph.links, graph.poses)
    doubts = scan_doubts(graph.links, graph.paths, loops)
    assert doubts == (frozenset(), {(0, 1)}, {(0, 1), (1, 2)}, None)
    statuses = ("registered", "needs review", "needs review", "failed")
    states = [scan_state(s, d, {(0, 1)}) for s, d in zip(statuses, doubts, strict=True)]
    assert states == ["registered", ACCEPTED, "needs review", "failed"]
    both = {(0, 1), (1, 2)}
    states = [scan_state(s, d, both) for s, d in zip(statuses, doubts, strict=True)]
    assert states == ["registered", ACCEPTED, ACCEPTED, "failed"]


def test_no_acceptance_clears_two_registered_links_that_disagree():
    links = [
        link(0, 1, "verified", 0.5),
        link(1, 2, "verified", 0.5),
        link(0, 2, "verified", 0.1, shift=3.0),
    ]
    graph = spanning_tree(links, 3, 0)
    loops = loop_closures(graph.links, graph.poses)
    doubts = scan_doubts(graph.links, graph.paths, loops)
    assert doubts[1] is None
    assert doubts[2] is None
    every = {(0, 1), (1, 2), (0, 2)}
    assert scan_state("needs review", doubts[2], every) == "needs review"


def test_the_app_s_review_holds_for_the_same_files_typed_as_relative_paths(
    tmp_path, monkeypatch: pytest.MonkeyPatch
):
    absolute = [str(tmp_path / "s" / "a.ply"), str(tmp_path / "s" / "b.e57") + "#1"]
    write_review(tmp_path, absolute, PlotReview({"T001": "ok"}))
    monkeypatch.chdir(tmp_path / "..")
    typed = [f"{tmp_path.name}/s/a.ply", f"./{tmp_path.name}/s/../s/b.e57#1"]
    assert read_review(tmp_path, typed).marks == {"T001": "ok"}
    assert read_review(tmp_path, [typed[1], typed[0]]) == PlotReview()


def test_a_review_holds_for_its_scans_moved_but_not_for_other_scans(tmp_path):
    # A plot's folder copied from the field laptop: the same files elsewhere.
    field, office = tmp_path / "field", tmp_path / "office"
    field.mkdir()
    labels = [str(field / "a.ply"), str(field / "b.e57") + "#1"]
    (field / "a.ply").write_bytes(b"ply\n" + bytes(range(256)) * 600)
    (field / "b.e57").write_bytes(b"e57" * 70_000)
    write_review(tmp_path, labels, PlotReview({"T001": "ok"}))
    field.rename(office)
    # A mark made in the app while the scans are away keeps what finds them again.
    write_review(tmp_path, labels, PlotReview({"T001": "ok", "T002": "check"}))
    moved = [str(office / "a.ply"), str(office / "b.e57") + "#1"]
    assert read_review(tmp_path, moved).marks == {"T001": "ok", "T002": "check"}
    write_review(tmp_path, labels, PlotReview({"T001": "ok"}))
    assert read_review(tmp_path, moved).marks == {"T001": "ok"}
    # Another second scan around the same reference: the trees' review holds.
    assert read_review(tmp_path, [moved[0], moved[1][:-1] + "0"]).marks == {
        "T001": "ok"
    }
    # The same names holding other points are other scans.
    (office / "a.ply").write_bytes(b"ply\n" + bytes(range(256)) * 601)
    assert read_review(tmp_path, moved) == PlotReview()
    (office / "a.ply").unlink()  # and a file that is gone matches nothing
    assert read_review(tmp_path, moved) == PlotReview()


def test_a_report_of_a_folder_without_a_plot_is_one_line(tmp_path):
    from amrst.plot.export import write_report

    with pytest.raises(InvalidInput, match="run the plot again") as err:
        write_report(tmp_path)
    assert "\n" not in str(err.value)
    (tmp_path / "plot.json").write_text("{}")
    os.mkfifo(tmp_path / "trees.csv")  # reading it would wait for ever
    with pytest.raises(InvalidInput, match=r"trees\.csv is not a file"):
        write_report(tmp_path)


def test_a_dbh_by_hand_is_the_circle_through_the_clicks():
    a = np.radians([10.0, 80.0, 150.0, 200.0])
    clicks = np.column_stack([3 + 0.2 * np.cos(a), -1 + 0.2 * np.sin(a)])
    circle = hand_circle(clicks)
    assert circle is not None
    assert circle.centre_xy == pytest.approx((3.0, -1.0))
    assert circle.dbh_m == pytest.approx(0.4)
    # Too few clicks, or clicks along a line, bound no stem.
    assert hand_circle(clicks[:2]) is None
    assert hand_circle([[0, 0], [0.1, 0.1], [0.2, 0.2]]) is None
    assert hand_circle([[0, 0], [0.1, 0.1], [np.nan, 0.2]]) is None
    assert hand_circle([[0, 0], [3.0, 0.0001], [6.0, 0.0]]) is None  # 90 km wide


def test_a_bad_dbh_by_hand_is_not_written(tmp_path):
    with pytest.raises(InvalidInput, match="T001: a DBH by hand"):
        write_review(tmp_path, LABELS, PlotReview(dbh={"T001": HandCircle((0, 0), 0)}))
    for added in ({"T001": (1.0, 1.0)}, {"H001": (float("nan"), 1.0)}):
        with pytest.raises(InvalidInput, match="Not saved"):
            write_review(tmp_path, LABELS, PlotReview(added=added))
    assert not (tmp_path / "review.json").exists()


def test_an_added_tree_taken_back_leaves_the_others_their_ids():
    from amrst.plot.review import next_added_id, without_added

    review = PlotReview(
        {"T001": "ok", "H001": "check", "H002": "ok", "H003": "not a tree"},
        dbh={"H002": HandCircle((0, 0), 0.2)},
        added={"H001": (0.0, 0.0), "H002": (1.0, 1.0), "H003": (2.0, 2.0)},
    )
    back = without_added(review, "H002")
    assert back.added == {"H001": (0.0, 0.0), "H003": (2.0, 2.0)}
    assert back.marks == {"T001": "ok", "H001": "check", "H003": "not a tree"}
    assert back.dbh == {}
    assert next_added_id(back) == "H004"  # an id is not given twice
    assert next_added_id(PlotReview()) == "H001"


def test_the_review_follows_its_trees_when_a_run_lists_them_otherwise(tmp_path):
    from amrst.plot.review import followed

    review = PlotReview(
        {"T001": "check", "T002": "ok", "T009": "ok"},
        dbh={"T002": HandCircle((5.0, 1.0), 0.3)},
        at={"T001": (0.0, 4.0), "T002": (5.0, 1.0)},  # T009: an older review's
    )
    # A new tree at (-9, 0) comes first: every id moves by one.
    now = {
        "T001": np.array([-9.0, 0.0]),
        "T002": np.array([0.02, 4.01]),
        "T003": np.array([5.0, 1.0]),
        "T009": np.array([7.0, 7.0]),
    }
    moved, changed, lost = followed(review, now)
    assert changed
    assert lost == []
    assert moved.marks == {"T002": "check", "T003": "ok", "T009": "ok"}
    assert moved.dbh == {"T003": HandCircle((5.0, 1.0), 0.3)}
    assert moved.at["T002"] == (0.02, 4.01)
    # Read back as written; the same run again moves nothing.
    write_review(tmp_path, LABELS, moved)
    assert read_review(tmp_path, LABELS).at == moved.at
    assert not followed(moved, now)[1]
    # A marked tree no longer listed takes its mark with it.
    gone, changed, lost = followed(review, {"T001": np.array([0.0, 4.0])})
    assert gone.marks == {"T001": "check", "T009": "ok"}
    assert gone.dbh == {}
    assert lost == ["T002 (ok)", "T002 (your DBH 30.0 cm)"]
    # A tree added stays while it is listed, under its id or found near it.
    added = PlotReview(added={"H001": (1.0, 1.0), "H002": (3.0, 3.0)})
    listed = {"H001": np.array([1.0, 1.0]), "T001": np.array([3.1, 3.0])}
    assert followed(added, listed) == (added, False, [])
    kept, changed, lost = followed(added, {"T001": np.array([3.1, 3.0])})
    assert (kept.added, changed, lost) == ({"H002": (3.0, 3.0)}, True, ["H001 (added)"])


def test_a_folder_of_inventory_files_but_no_plot_is_not_written_over(tmp_path):
    from amrst.plot.export import check_out

    (tmp_path / "trees.csv").write_text("the technician's own list\n")
    (tmp_path / "report.html").write_text("<p>theirs</p>")
    with pytest.raises(
        InvalidInput, match=r"holds report\.html, trees\.csv but no plot"
    ):
        check_out(tmp_path, overwrite=False)
    check_out(tmp_path, overwrite=True)  # asked for
    other = tmp_path / "other"
    other.mkdir()
    (other / "notes.txt").write_text("kept beside a plot")
    check_out(other, overwrite=False)  # files a run does not write are no matter
    (other / "trees").mkdir()
    (other / "trees" / "my_scan.ply").write_text("ply")
    check_out(other, overwrite=False)
    (other / "trees" / "T001.ply").write_text("ply")  # a name a run writes
    with pytest.raises(InvalidInput, match="holds trees/T"):
        check_out(other, overwrite=False)


def test_a_registration_folder_takes_a_plot_only_when_asked(tmp_path):
    from amrst.plot.export import check_out

    # amrst register's result: a plot beside it mixes two results.
    doc = {"target_file": "/scans/t.ply", "source_file": "/scans/s.ply"}
    (tmp_path / "transform.json").write_text(json.dumps(doc))
    (tmp_path / "metrics.json").write_text("{}")
    with pytest.raises(
        InvalidInput, match=r"holds the export of s\.ply onto t\.ply: a plot's"
    ):
        check_out(tmp_path, overwrite=False)
    check_out(tmp_path, overwrite=True)  # asked for


def test_a_results_folder_that_cannot_take_a_run_is_refused_before_it(tmp_path):
    from amrst.plot.export import check_out

    dangling = tmp_path / "dangling"
    dangling.symlink_to(tmp_path / "gone")
    with pytest.raises(InvalidInput, match="which does not exist"):
        check_out(dangling, overwrite=True)
    out = tmp_path / "out"
    out.mkdir()
    (out / "trees").write_text("not the folder of tree clouds")
    with pytest.raises(InvalidInput, match="is a file, where a run keeps its tree"):
        check_out(out, overwrite=True)


def test_one_scan_twice_is_named_for_what_it_is():
    from amrst.io.checks import refuse_same_points
    from amrst.types import Cloud

    a = Cloud(np.arange(30.0).reshape(10, 3))
    b = Cloud(a.xyz + 1.0)
    refuse_same_points([a, b], ["p.e57#0", "p.e57#1"])  # two scans
    with pytest.raises(InvalidInput, match=r"p\.e57#1 is given twice"):
        refuse_same_points([a, b, b], ["p.e57#0", "p.e57#1", "p.e57#1"])
    with pytest.raises(InvalidInput, match=r"copy\.ply holds the same points as a"):
        refuse_same_points([a, a], ["a.ply", "copy.ply"])


def test_one_scan_exported_again_is_the_same_scan(tmp_path):
    from amrst import io
    from amrst.io.checks import refuse_same_points
    from amrst.types import Cloud

    rng = np.random.default_rng(4)
    a = Cloud(rng.uniform(-20, 20, (5000, 3)), offset=np.array([512_000.0, 0, 0]))
    shuffled = a.select(rng.permutation(len(a)))
    io.write(tmp_path / "a.las", a)  # millimetres
    io.write(tmp_path / "a.xyz", shuffled)
    for label, copy in (
        ("a.las", io.read(tmp_path / "a.las")),
        ("a.xyz", io.read(tmp_path / "a.xyz")),
    ):
        with pytest.raises(InvalidInput, match=f"{label} holds the same points as a"):
            refuse_same_points([a, copy], ["a.ply", label])
    # The same place scanned again (4 mm of range noise) is another scan.
    again = Cloud(a.xyz + rng.normal(0, 0.004, a.xyz.shape), offset=a.offset)
    refuse_same_points([a, again], ["a.ply", "again.ply"])
