"""The Plot window: a plot's scans opened, run in the engine process, its stem map.

The plot is built here as the engine tests build theirs: a gently sloped ground and
upright stems (cylinders), each scan seeing the half of every stem that faces it, in
its own frame (the second turned and moved).
"""

from __future__ import annotations

import csv
import dataclasses
import json
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
import pytest
from _plots import STEMS, pose, scan
from PySide6.QtCore import QPoint, Qt
from PySide6.QtTest import QTest
from PySide6.QtWidgets import QMenu

from amrst.errors import InvalidInput
from amrst.plot.review import read_review
from amrst.types import Cloud, invert_transform

if TYPE_CHECKING:
    from collections.abc import Callable

    from PySide6.QtGui import QAction
    from pytestqt.qtbot import QtBot

    from amrst.plot.inventory import Tree
    from amrst_gui.main_window import MainWindow
    from amrst_gui.plot.window import PlotWindow


# The second scan's pose in the first's frame: turned 70 deg and moved.
SOURCE_POSE = pose(70.0, (3.0, 1.0, 0.0))


@pytest.fixture(scope="module")
def plot_files(tmp_path_factory: pytest.TempPathFactory) -> list[str]:
    """Two scans of the plot as PLY files; the first is the reference."""
    from amrst import io

    inv = invert_transform(SOURCE_POSE)
    source = scan((3.0, 1.0), STEMS, 2) @ inv[:3, :3].T + inv[:3, 3]
    folder = tmp_path_factory.mktemp("plot")
    files = [folder / "scan_1.ply", folder / "scan_2.ply"]
    for f, xyz in zip(files, (scan((-2.0, 0.0), STEMS, 1), source), strict=True):
        io.write(f, Cloud(xyz))
    return [str(f) for f in files]


def test_scanners_given_to_amrst_plot_hold_for_a_run_from_the_window(
    make_main_window: Callable[..., MainWindow],
    qtbot: QtBot,
    plot_files: list[str],
    tmp_path: Path,
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    from amrst.plot.cli import main as plot_main
    from amrst_gui.plot import window as plot_window

    out = tmp_path / "out"
    given = ["--scanner", "1", "-2", "0", "0"]  # the reference's scanner stood there
    assert plot_main([*plot_files, "--out", str(out), "--quiet", *given]) == 0
    win = make_main_window()
    plot = win.open_plot_results(out)
    qtbot.waitUntil(lambda: plot.outcome is not None, timeout=30_000)
    assert plot.scans.given_scanners == {0: (-2.0, 0.0, 0.0)}
    # Another plot is opened from the Plot window's menu too.
    texts = [a.text() for a in plot.plot_menu.actions()]
    assert texts[:3] == ["Open plot…", "Open plot results…", ""]
    # The window gives scan 2's (its file's origin) and refuses what is no position.
    plot.scans.scan_list.setCurrentRow(1)
    assert plot.scans.scanner_button.isEnabled()
    for typed in ("0 0", "12,5 3 1"):  # too few; a decimal comma
        plot.scans.set_scanner(typed)
        assert plot.status.text().startswith(
            "The scanner of S2: give X Y Z, three numbers with decimal points"
        )
    plot.scans.set_scanner("0, 0, nan")
    assert plot.status.text() == (
        "The scanner of scan 2 at 0 0 nan: give X Y Z as numbers within 1e+09 m "
        "(metres)."
    )
    assert plot.scans.given_scanners == {0: (-2.0, 0.0, 0.0)}
    plot.scans.set_scanner("0, 0, 0")
    assert plot.scans.given_scanners == {0: (-2.0, 0.0, 0.0), 1: (0.0, 0.0, 0.0)}
    item = plot.scans.scan_list.item(1)
    assert item.text().endswith("; scanner given")
    assert item.toolTip().endswith(
        "\nScanner given at 0.00, 0.00, 0.00 m, in the file's coordinates"
    )
    monkeypatch.setattr(plot_window, "confirm", lambda *_: True)  # replace the plot
    _run(qtbot, plot)
    doc = json.loads((out / "plot.json").read_text())
    assert [s["scanner_given"] for s in doc["scans"]] == [[-2.0, 0.0, 0.0], [0.0] * 3]
    assert plot.scans.given_scanners == {0: (-2.0, 0.0, 0.0), 1: (0.0, 0.0, 0.0)}
    assert plot.scans.scan_list.item(1).text().endswith("; scanner given")
    plot.scans.set_scanner("")  # forgotten: the next run goes by the file
    assert plot.scans.given_scanners == {0: (-2.0, 0.0, 0.0)}
    assert "given" not in plot.scans.scan_list.item(1).text()
    assert "given" not in plot.scans.scan_list.item(1).toolTip()
    assert (
        plot.scans.scan_list.item(1).toolTip().endswith(plot.scans.specs[1])
    )  # whole path


@pytest.fixture(scope="module")
def plot_run(plot_files: list[str], tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The two scans' plot as ``amrst plot`` writes it, once; tests open a copy."""
    from amrst.plot.cli import main as plot_main

    out = tmp_path_factory.mktemp("plot_run") / "out"
    assert plot_main([*plot_files, "--out", str(out), "--quiet"]) == 0
    return out


def _shown(qtbot: QtBot, plot_run: Path, tmp_path: Path) -> tuple[PlotWindow, Path]:
    """A shown Plot window with a copy of ``plot_run`` opened, and the copy."""
    import shutil

    from amrst_gui.plot.window import PlotWindow

    out = tmp_path / "out"
    shutil.copytree(plot_run, out)
    plot = PlotWindow()
    qtbot.addWidget(plot)
    plot.show()
    with qtbot.waitSignal(plot.plot_done, timeout=30_000):
        plot.open_results(out)
    return plot, out


def _run(qtbot: QtBot, plot: PlotWindow) -> None:
    with qtbot.waitSignal(plot.plot_done, timeout=300_000):
        plot.run()


def _measure_by_hand(plot: PlotWindow, k: int, out: Path) -> None:
    """The technician's DBH: clicks on the stem's outline at 1.3 m, kept, forgotten."""
    from amrst.plot.export import TREES_CSV
    from amrst_gui.plot.tree import SIDE

    o = plot.outcome
    assert o is not None
    tree, panel = o.trees[k], plot.tree_panel
    view = panel.slice_view
    panel.height_buttons.button(3).click()  # measuring turns to breast height
    assert not panel.keep_button.isEnabled()
    panel.measure_button.click()
    assert view.measuring
    assert "at 1.3 m" in view.note
    r = tree.stem.dbh_m / 2
    a = np.radians([200.0, 250.0, 300.0, 330.0, 0.0])  # the side scan 1 faced
    rim = np.asarray(tree.stem.dbh_xy) + r * np.column_stack([np.cos(a), np.sin(a)])
    for n, (x, y) in enumerate(view.to_px(rim), 1):
        QTest.mouseClick(
            view, Qt.MouseButton.LeftButton, pos=QPoint(round(x), round(y))
        )
        assert panel.keep_button.isEnabled() == (n >= 3)
    QTest.mouseClick(view, Qt.MouseButton.RightButton, pos=QPoint(5, 5))
    assert len(view.clicks) == 4  # the last taken back
    circle = view.circle()
    assert circle is not None
    assert abs(circle.dbh_m - 2 * r) < 0.01  # a pixel is a few mm here
    QTest.keyClick(view, Qt.Key.Key_Return)  # as Keep DBH
    assert not view.measuring
    kept = read_review(out, o.labels).dbh
    assert list(kept) == [tree.tree_id]
    assert kept[tree.tree_id].dbh_m == pytest.approx(circle.dbh_m)
    with (out / TREES_CSV).open() as fh:
        hand = {r["tree_id"]: r["dbh_hand_m"] for r in csv.DictReader(fh)}
    assert float(hand.pop(tree.tree_id)) == pytest.approx(circle.dbh_m, abs=1e-3)
    assert set(hand.values()) == {""}
    assert "yours" in panel.values["DBH"].text()
    assert plot.stem_map.review.dbh == kept  # drawn so
    panel.height_buttons.button(SIDE).click()
    assert panel.side_view.hand == kept[tree.tree_id]  # a green bar by the white
    cell = plot.trees.table.item(k, 2)
    assert cell is not None
    assert cell.text() == "yours"
    assert panel.forget_button.isEnabled()
    panel.forget_button.click()
    assert read_review(out, o.labels).dbh == {}
    assert "yours" not in panel.values["DBH"].text()
    panel.measure_button.click()
    QTest.keyClick(view, Qt.Key.Key_Escape)  # cancels
    assert not view.measuring
    assert not panel.measure_button.isChecked()


def test_a_plot_runs_and_its_stem_map_shows_every_tree(
    make_main_window: Callable[..., MainWindow],
    qtbot: QtBot,
    plot_files: list[str],
    tmp_path: Path,
    monkeypatch: pytest.MonkeyPatch,
    opened_reports: list[Path],
) -> None:
    from amrst.plot.export import TREES_CSV
    from amrst_gui.plot import window as plot_window

    win = make_main_window()
    out = tmp_path / "out"
    plot = win.open_plot(plot_files, out)
    assert plot.isVisible()
    assert plot.scans.scan_list.count() == 2
    _run(qtbot, plot)
    o = plot.outcome
    assert o is not None
    assert not o.missing
    assert [ln.status for ln in o.links] == ["registered"]
    for k, place in enumerate(o.scans):  # each scan on the other's surfaces
        assert 0 < place.residual_m < 0.02
        assert (
            f"residual {place.residual_m * 100:.1f}"
            in plot.scans.scan_list.item(k).text()
        )
    # Every tree once, where it stands in the reference scan, its DBH measured.
    assert len(o.trees) == len(STEMS)
    for x, y, r, _h in STEMS:
        d = np.hypot(*(o.tree_xy - (x, y)).T)
        k = int(np.argmin(d))
        assert d[k] < 0.1
        assert abs(o.trees[k].stem.dbh_m - 2 * r) < 0.02
    assert plot.trees.table.rowCount() == len(STEMS)
    with (out / TREES_CSV).open() as fh:
        assert len(list(csv.DictReader(fh))) == len(STEMS)

    # Each tree is drawn where a click finds it; a click selects it everywhere.
    px = plot.stem_map.to_px(o.tree_xy)
    assert [plot.stem_map.tree_at(x, y) for x, y in px] == list(range(len(STEMS)))
    k = 2
    QTest.mouseClick(
        plot.stem_map,
        Qt.MouseButton.LeftButton,
        Qt.KeyboardModifier.NoModifier,
        QPoint(round(px[k, 0]), round(px[k, 1])),
    )
    tree = o.trees[k]
    assert plot.stem_map.selected == k
    assert plot.tree_panel.tree_id == tree.tree_id
    assert plot.trees.table.currentRow() == k
    assert f"{tree.stem.dbh_m * 100:.1f} cm" in plot.tree_panel.values["DBH"].text()
    # Its slices: the points around the stem at 0.6-3 m lie on its circle (these
    # stems are straight cylinders), the 1.3 m one shown first, the fitted one.
    assert plot.tree_panel.slice_view.fitted
    assert "at 1.3 m" in plot.tree_panel.slice_view.note
    for sl in o.slices[k]:
        assert len(sl.xy) > 20
        rim = np.hypot(*(sl.xy - tree.stem.dbh_xy).T)
        assert abs(np.median(rim) - tree.stem.dbh_m / 2) < 0.01, sl.height_m
        assert set(np.unique(sl.scan)) <= {0, 1}
    plot.tree_panel.height_buttons.button(3).click()
    assert "at 3 m" in plot.tree_panel.slice_view.note
    assert not plot.tree_panel.slice_view.fitted  # the DBH circle only to compare
    QTest.mouseClick(
        plot.stem_map,
        Qt.MouseButton.LeftButton,
        Qt.KeyboardModifier.NoModifier,
        QPoint(round(px[0, 0]), round(px[0, 1])),
    )
    assert "at 3 m" in plot.tree_panel.slice_view.note  # the height holds
    _zoom_and_drag(plot)
    plot.select_tree(k)

    # A mark is saved beside the inventory at once, and read back with it.
    plot.tree_panel.buttons["check"].click()
    assert read_review(out, o.labels).marks == {tree.tree_id: "check"}
    (at,) = read_review(out, o.labels).at.values()  # where it stands: the mark follows
    assert np.allclose(at, tree.stem.dbh_xy)
    with (out / TREES_CSV).open() as fh:  # and the inventory handed over says it
        marked = {r["tree_id"]: r["mark"] for r in csv.DictReader(fh) if r["mark"]}
    assert marked == {tree.tree_id: "check"}
    # Exported elsewhere with the marks; a name it cannot write is one line.
    plot.export_inventory(str(tmp_path / "inventory.csv"))
    with (tmp_path / "inventory.csv").open() as fh:
        exported = {r["tree_id"]: r["mark"] for r in csv.DictReader(fh)}
    assert len(exported) == len(STEMS)
    assert exported[tree.tree_id] == "check"
    plot.export_inventory(str(tmp_path / "inventory.ods"))
    assert plot.status.text().startswith("Not exported:")
    assert ".csv or .xlsx" in plot.status.text()
    plot.export_inventory(str(tmp_path / "inventory.xlsx"))
    assert (tmp_path / "inventory.xlsx").stat().st_size > 0
    # The report says what the folder's files say, the mark included, and opens.
    opened = opened_reports
    plot.trees.report_button.click()
    qtbot.waitUntil(lambda: bool(opened), timeout=30_000)  # drawn off the GUI thread
    assert opened == [out / "report.html"]
    assert plot.trees.report_button.isEnabled()
    assert f"<td>{tree.tree_id}</td>" in opened[0].read_text()
    assert "1 marked check, 0 marked not a tree and 0 DBHs measured by you" in (
        opened[0].read_text()
    )
    # With no browser to open it, the status says where the report is.
    from amrst_gui import dialogs

    monkeypatch.setattr(dialogs, "open_report", lambda _parent, _path: False)
    plot.trees.report_button.click()
    qtbot.waitUntil(lambda: "No web browser" in plot.status.text(), timeout=30_000)
    assert str(out / "report.html") in plot.status.text()
    cell = plot.trees.table.item(k, 5)
    assert cell is not None
    assert cell.text() == "check"
    plot.tree_panel.buttons["not a tree"].click()  # a shrub listed as a tree
    assert read_review(out, o.labels).marks == {tree.tree_id: "not a tree"}
    assert plot.stem_map.review.marks == {tree.tree_id: "not a tree"}
    cell = plot.trees.table.item(k, 5)
    assert cell is not None
    assert cell.text() == "not a tree"
    plot.tree_panel.buttons[""].click()
    assert read_review(out, o.labels).marks == {}
    _review_by_keys(qtbot, plot, out)
    _sorted_by_dbh(plot)
    plot.select_tree(k)
    _measure_by_hand(plot, k, out)

    # Another run into the same folder asks first; "keep it" runs nothing.
    asked: list[str] = []

    def keep_it(_parent: object, title: str, text: str) -> bool:
        asked.append(f"{title} {text}")
        return False

    monkeypatch.setattr(plot_window, "confirm", keep_it)
    plot.run()
    assert len(asked) == 1
    assert "these scans" in asked[0]
    assert not plot.busy
    assert "is kept as it is" in plot.status.text()
    _add_a_tree(qtbot, plot, out, monkeypatch)


def _zoom_and_drag(plot: PlotWindow) -> None:
    """The wheel zooms about the cursor, a drag moves the map and selects nothing,
    a double click shows the whole plot."""
    from PySide6.QtCore import QPointF
    from PySide6.QtGui import QWheelEvent
    from PySide6.QtWidgets import QApplication

    view, o = plot.stem_map, plot.outcome
    assert o is not None
    x, y = view.to_px(o.tree_xy[1])[0]
    scale = view._mapping()[0]  # pixels per metre
    at = QPointF(x, y)
    wheel = QWheelEvent(
        at,
        view.mapToGlobal(at),
        QPoint(0, 0),
        QPoint(0, 240),  # two notches forward
        Qt.MouseButton.NoButton,
        Qt.KeyboardModifier.NoModifier,
        Qt.ScrollPhase.NoScrollPhase,
        False,
    )
    QApplication.sendEvent(view, wheel)
    assert view.zoom == pytest.approx(1.25**2)
    assert np.allclose(view.to_px(o.tree_xy[1])[0], (x, y), atol=0.5)  # held there
    assert view._mapping()[0] == pytest.approx(scale * 1.25**2)
    selected = view.selected
    start, end = QPoint(round(x), round(y)), QPoint(round(x) + 40, round(y) + 30)
    QTest.mousePress(view, Qt.MouseButton.LeftButton, pos=start)
    QTest.mouseMove(view, end)
    QTest.mouseRelease(view, Qt.MouseButton.LeftButton, pos=end)
    assert np.allclose(view.to_px(o.tree_xy[1])[0], (x + 40, y + 30), atol=1.0)
    assert view.selected == selected  # a drag is no click
    QTest.mouseDClick(view, Qt.MouseButton.LeftButton, pos=end)
    assert view.zoom == 1.0
    assert np.allclose(view.to_px(o.tree_xy[1])[0], (x, y), atol=1e-6)


def _sorted_by_dbh(plot: PlotWindow) -> None:
    """A heading sorts the table by its numbers; a row still shows its own tree."""
    o = plot.outcome
    assert o is not None
    plot.trees.table.sortByColumn(1, Qt.SortOrder.DescendingOrder)  # as a heading click
    dbh = [o.trees[_tree_in(plot, r)].stem.dbh_m for r in range(len(o.trees))]
    assert dbh == sorted(dbh, reverse=True)
    plot.trees.table.selectRow(0)  # the widest stem
    assert plot.tree_panel.tree_id == o.trees[_tree_in(plot, 0)].tree_id
    assert o.trees[_tree_in(plot, 0)].stem.dbh_m == max(dbh)
    plot.step_tree(1)  # N: the next row down, the next widest
    assert plot.tree_panel.tree_id == o.trees[_tree_in(plot, 1)].tree_id
    plot.set_mark(o.trees[_tree_in(plot, 1)].tree_id, "ok")  # the order holds
    assert plot.trees.table.currentRow() == 1
    plot.set_mark(o.trees[_tree_in(plot, 1)].tree_id, "")
    plot.trees.table.sortByColumn(0, Qt.SortOrder.AscendingOrder)  # the trees' order
    assert [_tree_in(plot, r) for r in range(len(o.trees))] == list(range(len(o.trees)))


def _tree_in(plot: PlotWindow, row: int) -> int:
    from amrst_gui.plot.tables import tree_at_row

    k = tree_at_row(plot.trees.table, row)
    assert k is not None
    return k


def _review_by_keys(qtbot: QtBot, plot: PlotWindow, out: Path) -> None:
    """N / P walk the tree list, O / C / X mark the tree shown, Del clears."""
    o = plot.outcome
    assert o is not None

    def marks_become(marks: dict[str, str]) -> None:  # a button's key clicks it soon
        qtbot.waitUntil(lambda: read_review(out, o.labels).marks == marks)

    plot.activateWindow()
    qtbot.waitUntil(plot.isActiveWindow)
    plot.select_tree(0)
    first, second = o.trees[0].tree_id, o.trees[1].tree_id
    QTest.keyClick(plot.trees.table, Qt.Key.Key_N)
    assert plot.tree_panel.tree_id == second
    QTest.keyClick(plot.trees.table, Qt.Key.Key_O)
    marks_become({second: "ok"})
    QTest.keyClick(plot.trees.table, Qt.Key.Key_P)
    QTest.keyClick(plot.trees.table, Qt.Key.Key_P)  # stays at the first
    assert plot.tree_panel.tree_id == first
    QTest.keyClick(plot.trees.table, Qt.Key.Key_X)
    marks_become({first: "not a tree", second: "ok"})
    QTest.keyClick(plot.trees.table, Qt.Key.Key_Delete)
    marks_become({second: "ok"})
    QTest.keyClick(plot.trees.table, Qt.Key.Key_N)
    QTest.keyClick(plot.trees.table, Qt.Key.Key_Delete)
    marks_become({})
    plot.area_row.centre_edit.setEnabled(True)
    plot.area_row.centre_edit.setFocus()  # typed into a field, a letter is text
    QTest.keyClick(plot.area_row.centre_edit, Qt.Key.Key_C)
    qtbot.wait(300)
    assert read_review(out, o.labels).marks == {}
    plot.area_row.centre_edit.clear()


def _add_a_tree(
    qtbot: QtBot, plot: PlotWindow, out: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A tree the list misses: added on the map, taken back, added, then measured."""
    from amrst_gui.plot import window as plot_window

    o = plot.outcome
    assert o is not None
    gap = (1.0, -1.0)  # bare ground between the stems

    def click_at(xy: tuple[float, float]) -> None:
        plot.trees.add_button.click()
        assert plot.stem_map.adding
        ((x, y),) = plot.stem_map.to_px(np.array(xy))
        QTest.mouseClick(
            plot.stem_map, Qt.MouseButton.LeftButton, pos=QPoint(round(x), round(y))
        )
        assert not plot.stem_map.adding  # one click, one tree

    click_at(tuple(o.tree_xy[0]))  # a listed tree is listed once
    assert "stands there" in plot.status.text()
    assert read_review(out, o.labels).added == {}
    click_at(gap)
    (added,) = read_review(out, o.labels).added.values()
    assert np.hypot(*np.subtract(added, gap)) < 0.1
    assert plot.stem_map.pending() == ["H001"]
    assert "H001 added" in plot.status.text()
    click_at(gap)  # the cross again: taken back
    assert read_review(out, o.labels).added == {}
    click_at(gap)
    monkeypatch.setattr(plot_window, "confirm", lambda *_: True)
    _run(qtbot, plot)
    o = plot.outcome
    assert o is not None
    assert [t.tree_id for t in o.trees][-1] == "H001"  # after the trees found
    assert len(o.trees) == len(STEMS) + 1
    assert plot.stem_map.pending() == []
    click_at(gap)  # a measured one stays: Not a tree drops it
    assert "mark it Not a tree" in plot.status.text()
    assert len(read_review(out, o.labels).added) == 1


def test_a_plot_in_one_e57_file_is_listed_and_run_scan_by_scan(
    make_main_window: Callable[..., MainWindow],
    qtbot: QtBot,
    plot_files: list[str],
    tmp_path: Path,
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    from _writers import write_e57

    from amrst import io
    from amrst_gui.plot import window as plot_window

    pytest.importorskip("pye57")
    e57 = tmp_path / "plot.e57"
    setups = [
        dataclasses.replace(io.read(f), name=f"Setup {k + 1}")
        for k, f in enumerate(plot_files)
    ]
    write_e57(e57, setups, [np.eye(4), np.eye(4)])
    plot = make_main_window().open_plot([str(e57)], tmp_path / "out")
    assert plot is not None
    assert plot.listing
    _run(qtbot, plot)  # asked for while the scans are listed: it runs once they are
    lines = [
        plot.scans.scan_list.item(k).text() for k in range(plot.scans.scan_list.count())
    ]
    assert [line.split(":")[0] for line in lines] == [
        "S1  plot.e57#0 (Setup 1)",
        "S2  plot.e57#1 (Setup 2)",
    ]
    assert plot.outcome is not None
    assert [Path(s).name for s in plot.outcome.labels] == ["plot.e57#0", "plot.e57#1"]
    asked: list[str] = []
    monkeypatch.setattr(plot_window, "confirm", lambda _p, _t, text: asked.append(text))
    plot.run()  # the same scans: asked about replacing, not about another plot
    assert "a plot of these scans" in asked[0]
    # Listed once: another reference is chosen among the scans as listed.
    plot.open_scans([str(e57)])
    qtbot.waitUntil(lambda: plot.scans.scan_list.count() == 2, timeout=60_000)
    plot.scans.scan_list.setCurrentRow(1)
    plot.scans.make_reference()
    assert plot.job is None
    assert [plot.scans.scan_list.item(k).text() for k in range(2)] == [
        "S1  plot.e57#1 (Setup 2)",
        "S2  plot.e57#0 (Setup 1)",
    ]
    # A file that is not an E57 is one line, and nothing is listed.
    bad = tmp_path / "bad.e57"
    bad.write_text("not an e57 file")
    plot.open_scans([str(bad), plot_files[0]])
    qtbot.waitUntil(lambda: plot.job is None, timeout=60_000)
    assert plot.scans.scan_list.count() == 0
    assert plot.status.text().startswith("Not opened: ")
    assert "bad.e57" in plot.status.text()
    assert "\n" not in plot.status.text()


def test_a_plot_run_cancels_and_a_bad_scan_is_one_line(
    make_main_window: Callable[..., MainWindow],
    qtbot: QtBot,
    plot_files: list[str],
    tmp_path: Path,
) -> None:
    from amrst.plot.export import PLOT_JSON

    win = make_main_window()
    out = tmp_path / "out"
    plot = win.open_plot(plot_files, out)
    plot.run()
    assert plot.busy
    assert plot.cancel_button.isEnabled()
    plot.set_mark("T001", "ok")  # the run writes the same files
    assert "a plot is running" in plot.status.text()
    qtbot.wait(300)
    plot.cancel()
    qtbot.waitUntil(lambda: not plot.busy, timeout=5_000)
    assert "cancelled" in plot.status.text()
    assert not (out / PLOT_JSON).exists()
    assert plot.run_button.isEnabled()

    plot.open_scans([plot_files[0], str(tmp_path / "missing.ply")], out)
    plot.run()
    qtbot.waitUntil(lambda: not plot.busy, timeout=60_000)
    text = plot.status.text()
    assert text.startswith("The plot failed:")
    assert "missing.ply" in text
    assert "\n" not in text
    assert plot.outcome is None


def test_closing_the_app_cancels_a_plot_run_rather_than_waiting_for_it(
    make_main_window: Callable[..., MainWindow],
    qtbot: QtBot,
    plot_files: list[str],
    tmp_path: Path,
) -> None:
    from amrst.plot.export import PLOT_JSON

    win = make_main_window()
    out = tmp_path / "out"
    plot = win.open_plot(plot_files, out)
    plot.run()
    qtbot.wait(300)
    assert plot.busy
    win.close()  # waits for the worker threads: the plot's must be cancelled first
    assert not plot.busy
    qtbot.wait(500)
    assert not (out / PLOT_JSON).exists()


def test_a_step_waiting_for_the_plot_run_says_so_and_cancels(
    make_main_window: Callable[..., MainWindow],
    qtbot: QtBot,
    plot_files: list[str],
    tmp_path: Path,
) -> None:
    win = make_main_window()
    session = win.session
    with qtbot.waitSignal(session.busy_changed, timeout=20_000):
        win.open_pair(*plot_files)
    qtbot.waitUntil(lambda: not session.busy, timeout=30_000)
    said: list[str] = []
    session.progressed.connect(lambda _f, text: said.append(text))
    plot = win.open_plot(plot_files, tmp_path / "out")
    plot.run()
    qtbot.waitUntil(  # its turn in the engine process (the scans' descriptions end)
        lambda: (
            plot.status.text().startswith("Running: ")
            and "Waiting" not in plot.status.text()
        ),
        timeout=30_000,
    )
    assert plot.busy
    session.run_step("separate")  # one engine process: it waits its turn
    qtbot.waitUntil(lambda: bool(said), timeout=10_000)
    assert said[0] == "Waiting for the plot run in the Plot window to end…"
    session.cancel()
    qtbot.waitUntil(lambda: not session.busy, timeout=10_000)
    assert plot.busy or plot.outcome is not None  # the plot went on
    qtbot.waitUntil(lambda: not plot.busy, timeout=120_000)
    assert plot.outcome is not None


def test_the_command_line_opens_a_plot() -> None:
    from amrst_gui.__main__ import parse_args

    args = parse_args(["--plot", "a.ply", "b.ply", "--out", "res"])
    assert [p.name for p in args.plot] == ["a.ply", "b.ply"]
    assert args.out.name == "res"
    with pytest.raises(SystemExit):
        parse_args(["--plot", "a.ply"])
    # One E57 or PTX file may hold every scan of the plot.
    assert [p.name for p in parse_args(["--plot", "plot.e57"]).plot] == ["plot.e57"]
    assert parse_args(["--plot", "plot.PTX"]).plot is not None
    assert parse_args(["--plot-results", "res"]).plot_results.name == "res"
    with pytest.raises(SystemExit):
        parse_args(["--plot-results", "res", "--run", "all"])


def test_a_link_a_loop_confirms_reads_registered_in_the_links_table(tmp_path):
    from amrst_gui.plot.jobs import LinkLine, PlotOutcome
    from amrst_gui.plot.tables import link_rows

    def line(confirmed):
        status = "registered" if confirmed else "needs review"
        return LinkLine(0, 1, status, confirmed, True, "stems", 0.4, 0.06, 8, "")

    outcome = PlotOutcome(
        tmp_path, ("a", "b"), (), (), (line(True), line(False)), 0.01, (), None, 1.0
    )
    rows = link_rows(outcome)
    assert [r[1] for r in rows] == ["registered (loop)", "needs review"]


def test_the_links_table_is_as_tall_as_its_links(qtbot: QtBot, tmp_path) -> None:
    # Two positions make one link: the rows it does not need go to the tree list.
    from amrst_gui.plot.jobs import LinkLine, PlotOutcome
    from amrst_gui.plot.links import LinksPanel, link_rows_shown
    from amrst_gui.plot.tables import ROW_PX

    def outcome(n: int) -> PlotOutcome:
        lines = tuple(
            LinkLine(0, k, "registered", True, True, "stems", 0.4, 0.01, 6, "")
            for k in range(1, n + 1)
        )
        names = tuple(f"s{k}" for k in range(n + 1))
        return PlotOutcome(tmp_path, names, (), (), lines, 0.01, (), None, 1.0)

    panel = LinksPanel()
    qtbot.addWidget(panel)
    heights = {}
    for n in (1, 2, 3, 10):
        panel.show_links(outcome(n))
        heights[n] = panel.table.height()
    assert heights[1] == heights[2] < heights[3] < heights[10]
    # Ten links (five positions) scroll past six rows on a laptop screen rather than
    # crowd the trees; a tall screen has room for them all.
    panel.show_links(outcome(10))
    assert panel.table.rowCount() == 10
    assert [link_rows_shown(10, h) for h in (768, 1080)] == [6, 10]
    assert link_rows_shown(1, 1080) == 2
    assert heights[10] == panel.table.height() >= 6 * ROW_PX


def test_a_link_is_placed_from_point_pairs_picked_in_the_main_window(
    make_main_window: Callable[..., MainWindow],
    qtbot: QtBot,
    plot_files: list[str],
    tmp_path: Path,
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    from amrst.plot.register import HAND_ORIGIN
    from amrst.review.pairs_file import write_pairs
    from amrst_gui.plot import window as plot_window

    win = make_main_window()
    plot = win.open_plot(plot_files, tmp_path / "out")
    assert not plot.links.open_button.isEnabled()  # no link yet
    _run(qtbot, plot)
    assert plot.outcome is not None
    assert plot.outcome.links[0].origin != HAND_ORIGIN
    plot.links.table.selectRow(0)
    assert plot.links.open_button.isEnabled()

    # Open pair shows the link's two scans at its pose, Manual pose in front.
    session = win.session
    with qtbot.waitSignal(session.busy_changed, timeout=20_000):
        plot.links.open_button.click()
    qtbot.waitUntil(lambda: not session.busy, timeout=30_000)
    assert [session.path(r).name for r in ("target", "source")] == [
        "scan_1.ply",
        "scan_2.ply",
    ]
    assert not win.docks["manual"].visibleRegion().isEmpty()
    stored = session.stored
    assert stored is not None
    assert stored.label == "plot link S1–S2"
    assert stored.verdict["status"] == "registered"
    # The confidence shown is the one the link's status was judged by.
    assert stored.confidence == plot.outcome.links[0].confidence > 0.5
    assert (
        f"confidence {stored.confidence:.0%}" in win.matches_panel.coarse_label.text()
    )
    assert session.fine is not None
    shown = session.world(session.fine.T_target_source)
    assert np.allclose(shown, plot.outcome.links[0].T_world, atol=1e-9)
    # A plot is no one stem: the Stem slices tab sends the user to each tree's.
    assert session.plot_pair
    win.tabs.setCurrentWidget(win.slices)
    assert "Plot window" in win.slices.view.caption
    assert win.slices.view.slices == []
    # The same files opened as a pair of their own are no plot link any more.
    guard, session.discard_guard = (
        session.discard_guard,
        lambda _action, _lost, _keep: True,
    )
    with qtbot.waitSignal(session.busy_changed, timeout=20_000):
        win.open_pair(*plot_files)
    qtbot.waitUntil(lambda: not session.busy, timeout=30_000)
    assert not session.plot_pair
    win.tabs.setCurrentWidget(win.slices)  # loading shows the scans' tab
    assert "Plot window" not in win.slices.view.caption
    session.discard_guard = guard
    with qtbot.waitSignal(session.busy_changed, timeout=20_000):
        plot.links.open_button.click()
    qtbot.waitUntil(lambda: not session.busy, timeout=30_000)
    assert session.plot_pair
    # The main window refuses while it runs a step: the plot window says so.
    session.run_step("separate")
    assert session.busy
    plot.links.open_button.click()
    assert plot.status.text().startswith("S1 and S2 are not open: Cannot open scans")
    session.cancel()
    qtbot.waitUntil(lambda: not session.busy, timeout=30_000)

    # Four stem points picked in both scans (the source's under its true pose).
    picked = np.array([(x, y, 1.0) for x, y, *_ in STEMS[:4]])
    inv = invert_transform(SOURCE_POSE)
    in_source = picked @ inv[:3, :3].T + inv[:3, 3]
    swapped = tmp_path / "swapped.csv"  # the source's rows in another order
    write_pairs(swapped, picked, in_source[[1, 2, 3, 0]])
    plot.links.toggle_pairs(str(swapped))
    assert plot.links.hand_pairs == {}
    assert plot.status.text().startswith("Not used: the point pairs of swapped.csv")
    assert "same point in both scans" in plot.status.text()
    pairs = tmp_path / "pairs.csv"
    write_pairs(pairs, picked, in_source)

    class _Chosen:  # the file dialog, answered with the pairs file
        @staticmethod
        def getOpenFileName(*_args, **_kwargs) -> tuple[str, str]:
            return str(pairs), ""

    monkeypatch.setattr("amrst_gui.plot.links.QFileDialog", _Chosen)
    plot.links.pairs_button.click()  # Use pairs… asks for the file
    assert plot.links.hand_pairs == {(0, 1): str(pairs)}
    assert plot.links.pairs_button.text() == "Drop pairs"
    by = plot.links.table.item(0, 5)
    assert by is not None
    assert by.text() == "your pairs"  # the next run places it from the file
    monkeypatch.setattr(plot_window, "confirm", lambda *_: True)  # the same plot
    plot.cloud_check.setChecked(True)  # and the registered plot this time
    _run(qtbot, plot)
    assert (tmp_path / "out" / "plot.laz").is_file()
    link = plot.outcome.links[0]
    assert link.origin == HAND_ORIGIN
    assert link.status == "registered", link.message
    cell = plot.links.table.item(0, 5)
    assert cell is not None
    assert cell.text() == "your pairs"  # and again at the next run
    plot.cloud_check.setChecked(False)
    plot.open_scans(plot_files, tmp_path / "out")  # opened again: keep writing it
    assert plot.cloud_check.isChecked()

    # The results opened again, later: the link still comes from the pairs.
    plot.close()
    with qtbot.waitSignal(plot.plot_done, timeout=30_000):
        win.open_plot_results(tmp_path / "out")
    assert plot.links.hand_pairs == {(0, 1): str(pairs.resolve())}
    placed = [s.xy for s in plot.outcome.scans]  # where the scans stood, from poses
    assert np.allclose(placed[0], 0.0, atol=1e-9)
    assert np.allclose(placed[1], SOURCE_POSE[:2, 3], atol=0.01)
    assert plot.scans.specs == [str(Path(f).resolve()) for f in plot_files]
    assert plot.outcome is not None
    assert len(plot.outcome.trees) == len(STEMS)
    assert "opened from" in plot.status.text()


def test_a_link_that_needs_review_is_accepted_at_its_pose(
    qtbot: QtBot, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    from dataclasses import replace

    from amrst_gui.plot import window as plot_window
    from amrst_gui.plot.jobs import LinkLine, PlotOutcome, ScanPlace
    from amrst_gui.plot.tree import figures

    plot = plot_window.PlotWindow()
    qtbot.addWidget(plot)
    T = SOURCE_POSE
    line = LinkLine(
        0, 1, "needs review", False, True, "stems", 0.4, 0.02, 5, "unsure", 0.2, T
    )
    scans = (
        ScanPlace("a.ply", np.zeros(2), 5, "registered"),
        ScanPlace("b.ply", T[:2, 3], 5, "needs review", frozenset({(0, 1)})),
    )
    trees = (_tree("T001", (1, 2)), _tree("T002", (1,)))
    found = PlotOutcome(
        tmp_path, ("a.ply", "b.ply"), trees, scans, (line,), 0.01, (), None, 1.0
    )
    doc = {
        "scans": [{"status": s.status, "state": s.status} for s in scans],
        "links": [{"target": 0, "source": 1, "accepted": False}],
    }
    (tmp_path / "plot.json").write_text(json.dumps(doc))
    plot.open_scans(["a.ply", "b.ply"], tmp_path)
    plot._on_result(found)
    plot.links.table.selectRow(0)
    assert plot.links.accept_button.isEnabled()
    assert plot.links.accept_button.text() == "Accept"
    assert "S2, which needs review" in plot.trees.table.item(0, 0).toolTip()  # T001
    assert plot.trees.table.item(1, 0).toolTip() == ""  # T002, seen from S1 alone

    # Asked first; "Cancel" accepts nothing.
    monkeypatch.setattr(plot_window, "confirm", lambda *_: False)
    plot.links.accept_button.click()
    assert read_review(tmp_path, found.labels).accepted == {}
    monkeypatch.setattr(plot_window, "confirm", lambda *_: True)
    plot.links.accept_button.click()
    o = plot.outcome
    assert o is not None
    assert [ln.status for ln in o.links] == ["accepted"]
    assert [s.status for s in o.scans] == ["registered", "accepted"]
    assert "accepted" in plot.scans.scan_list.item(1).text()
    assert "1 accepted by you" in plot.status.text()
    assert plot.links.accept_button.text() == "Undo accept"
    (kept,) = read_review(tmp_path, found.labels).accepted.items()
    assert kept[0] == (0, 1)
    assert np.array_equal(kept[1], T)
    doc = json.loads((tmp_path / "plot.json").read_text())  # the handed-over states
    assert [s["state"] for s in doc["scans"]] == ["registered", "accepted"]
    assert [s["status"] for s in doc["scans"]] == ["registered", "needs review"]
    assert doc["links"][0]["accepted"]
    assert _scans_to_check(tmp_path) == {"T001": "", "T002": ""}
    assert plot.trees.table.item(0, 0).toolTip() == ""
    # A plot area given after the acceptance writes trees.csv as the review leaves it.
    plot.area_row.radius_spin.setValue(5.0)
    plot.apply_area()
    assert json.loads((tmp_path / "plot.json").read_text())["plot_area"] is not None
    assert _scans_to_check(tmp_path) == {"T001": "", "T002": ""}

    # A run again that finds the same pose keeps it accepted; another pose does not.
    plot._on_result(found)
    assert plot.outcome.links[0].status == "accepted"
    moved = replace(line, T_world=T @ pose(1.0, (0, 0, 0)))
    plot._on_result(replace(found, links=(moved,)))
    shown = plot.outcome.links[0]
    assert shown.status == "needs review"
    assert "You accepted a pose 1.00 deg" in shown.message
    assert plot.outcome.scans[1].status == "needs review"

    # Undo: the link needs review again, and the file says so.
    plot._on_result(found)
    plot.links.table.selectRow(0)
    plot.links.accept_button.click()
    assert plot.outcome.links[0].status == "needs review"
    assert read_review(tmp_path, found.labels).accepted == {}
    doc = json.loads((tmp_path / "plot.json").read_text())
    assert [s["state"] for s in doc["scans"]] == ["registered", "needs review"]
    # The tree scan 2 reaches rests on its pose again: trees.csv and its figures say so.
    assert _scans_to_check(tmp_path) == {"T001": "2", "T002": ""}
    seen = [
        dict(figures(t, plot.review, plot.outcome.unsure))["Seen from"] for t in trees
    ]
    assert "S2 needs review" in seen[0]
    assert "review" not in seen[1]


def test_labels_of_trees_side_by_side_do_not_overlap_until_zoomed(
    qtbot: QtBot, tmp_path: Path
) -> None:
    from amrst_gui.plot.jobs import PlotOutcome, ScanPlace
    from amrst_gui.plot.stem_map import StemMapView

    trees = (
        _tree("T001", (1,), 0.0),
        _tree("T002", (1,), 0.15),
        _tree("T003", (1,), 30),
    )
    # The scanner stands on T003: its label S1 goes where T003's would.
    scans = (ScanPlace("a.ply", np.array([30.0, 0.0]), 3, "registered"),)
    view = StemMapView()
    qtbot.addWidget(view)
    view.resize(600, 400)
    view.set_plot(PlotOutcome(tmp_path, ("a.ply",), trees, scans, (), 0.0, (), None, 1))
    labelled = [k for k, _ in view.tree_labels(view.to_px(view.outcome.tree_xy))]
    assert labelled in ([0], [1])  # 0.15 m apart: one label of the two; S1 over T003
    x, y = view.to_px(view.outcome.tree_xy[0])[0]
    view.zoom_at(x, y, 40.0)
    labelled = [k for k, _ in view.tree_labels(view.to_px(view.outcome.tree_xy))]
    assert {0, 1} <= set(labelled)
    view.select(1)  # the selected tree's label is always shown
    view.show_whole()
    assert 1 in [k for k, _ in view.tree_labels(view.to_px(view.outcome.tree_xy))]
    view.select(2)  # even beside a scanner's
    assert 2 in [k for k, _ in view.tree_labels(view.to_px(view.outcome.tree_xy))]
    # A tree added by hand beside T001 and T002: its label is drawn, theirs wait.
    from amrst.plot.review import PlotReview

    view.select(None)
    view.set_review(PlotReview(added={"H001": (1.0, 0.0)}))
    labelled = [k for k, _ in view.tree_labels(view.to_px(view.outcome.tree_xy))]
    assert not {0, 1} & set(labelled)


def test_the_stem_map_zooms_and_moves_by_keys(qtbot: QtBot, tmp_path: Path) -> None:
    from PySide6.QtCore import Qt

    from amrst_gui.plot.jobs import PlotOutcome, ScanPlace
    from amrst_gui.plot.stem_map import StemMapView

    trees = (_tree("T001", (1,), 0.0), _tree("T002", (1,), 10.0))
    scans = (ScanPlace("a.ply", np.array([5.0, 3.0]), 2, "registered"),)
    view = StemMapView()
    qtbot.addWidget(view)
    view.resize(600, 400)
    view.set_plot(PlotOutcome(tmp_path, ("a.ply",), trees, scans, (), 0.0, (), None, 1))
    assert view.focusPolicy() == Qt.FocusPolicy.StrongFocus  # Tab reaches it
    apart = np.ptp(view.to_px(view.outcome.tree_xy)[:, 0])
    qtbot.keyClick(view, Qt.Key.Key_Plus)
    assert view.zoom == 1.25
    assert np.ptp(view.to_px(view.outcome.tree_xy)[:, 0]) > apart
    x0 = view.to_px(view.outcome.tree_xy)[0, 0]
    qtbot.keyClick(view, Qt.Key.Key_Right)  # the view moves right: trees go left
    assert view.to_px(view.outcome.tree_xy)[0, 0] < x0
    qtbot.keyClick(view, Qt.Key.Key_Minus)
    qtbot.keyClick(view, Qt.Key.Key_Plus)
    qtbot.keyClick(view, Qt.Key.Key_0)  # whole again
    assert view.zoom == 1.0
    assert np.isclose(np.ptp(view.to_px(view.outcome.tree_xy)[:, 0]), apart)


def test_a_dbh_no_tree_has_draws_a_bounded_circle(qtbot: QtBot, tmp_path: Path) -> None:
    from dataclasses import replace

    from amrst_gui.plot.jobs import PlotOutcome, ScanPlace
    from amrst_gui.plot.stem_map import StemMapView

    tree = _tree("T001", (1,))
    edited = replace(tree, stem=replace(tree.stem, dbh_m=1e308))  # trees.csv by hand
    scans = (ScanPlace("a.ply", np.array([5.0, 0.0]), 1, "registered"),)
    view = StemMapView()
    qtbot.addWidget(view)
    view.resize(600, 400)
    view.set_plot(
        PlotOutcome(tmp_path, ("a.ply",), (edited,), scans, (), 0.0, (), None, 1)
    )
    radius = view._radii_px()
    assert np.isfinite(radius).all()
    view.grab()  # paints without an overflow


def test_the_status_says_why_no_tree_and_what_to_fix(
    qtbot: QtBot, tmp_path: Path
) -> None:
    from amrst_gui.panels.verdict_style import ERROR_STYLE
    from amrst_gui.plot import window as plot_window
    from amrst_gui.plot.jobs import LinkLine, PlotOutcome, ScanPlace

    plot = plot_window.PlotWindow()
    qtbot.addWidget(plot)
    scans = (
        ScanPlace("a.ply", np.zeros(2), 5, "registered"),
        ScanPlace("b.ply", None, 0, "failed", turned="with its y axis up"),
    )
    why = "no ground was found under the registered plot"
    swapped = "the file's target and source columns are swapped"
    by_hand = LinkLine(
        0, 1, "needs review", False, True, "manual", 0.4, 0.05, 0, swapped
    )
    found = PlotOutcome(
        tmp_path, ("a.ply", "b.ply"), (), scans, (by_hand,), 0.01, (), None, 1.0,
        no_tree_why=why,
    )  # fmt: skip
    plot.open_scans(["a.ply", "b.ply"], tmp_path)
    plot._on_result(found)
    assert plot.status.text().startswith("0 trees; 1 of 2 scans registered")
    assert f"No tree listed: {why}" in plot.status.text()
    assert "S2 seems to stand with its y axis up: export it z up" in plot.status.text()
    assert f"Your pairs of S1–S2: {swapped}" in plot.status.text()
    assert plot.status.styleSheet() == ERROR_STYLE


def test_every_column_of_the_tree_list_is_in_sight_at_1366x768(
    qtbot: QtBot, tmp_path: Path
) -> None:
    from dataclasses import replace

    from amrst_gui.plot import window as plot_window
    from amrst_gui.plot.jobs import PlotOutcome, ScanPlace

    plot = plot_window.PlotWindow()
    qtbot.addWidget(plot)
    plot.resize(1366, 768)
    plot.show()
    wide = _tree("T100", (1,))
    wide = replace(
        wide, stem=replace(wide.stem, dbh_m=1.064, height_flag="top not seen")
    )
    scans = (ScanPlace("a.ply", np.zeros(2), 5, "registered"),)
    found = PlotOutcome(tmp_path, ("a.ply",), (wide,), scans, (), 0.0, (), None, 1.0)
    plot.open_scans(["a.ply"], tmp_path)
    plot._on_result(found)
    plot.review = replace(plot.review, marks={"T100": "not a tree"})
    plot._show_marks()
    table = plot.trees.table
    qtbot.waitUntil(lambda: table.viewport().width() > 0)
    assert table.horizontalScrollBar().maximum() == 0  # nothing out of sight
    mark = table.item(0, table.columnCount() - 1)
    assert mark is not None
    assert mark.text() == "not a tree"
    width = table.fontMetrics().horizontalAdvance(mark.text())
    assert table.columnWidth(table.columnCount() - 1) > width


def _tree(tree_id: str, seen_from: tuple[int, ...], x: float | None = None) -> Tree:
    """A listed tree at ``x`` (m; else a place of its own), seen from ``seen_from``."""
    from amrst.plot.inventory import Tree
    from amrst.plot.stemmap import StemRecord

    at = np.array([float(tree_id[1:]) if x is None else x, 0.0, 0.0])
    stem = StemRecord(
        at, at[:2], 0.3, 300.0, 0.002, 0.05, "ok", 20.0, "ok", 1.0, 6.0, 5000
    )
    return Tree(tree_id, stem, at, seen_from)


def _scans_to_check(out: Path) -> dict[str, str]:
    with (out / "trees.csv").open() as fh:
        return {r["tree_id"]: r["scans_to_check"] for r in csv.DictReader(fh)}


def _one_link_shown(qtbot: QtBot, tmp_path: Path) -> tuple[PlotWindow, Any]:
    """A Plot window showing a run of two scans and their one registered link."""
    from amrst_gui.plot.jobs import LinkLine, PlotOutcome, ScanPlace
    from amrst_gui.plot.window import PlotWindow

    plot = PlotWindow()
    qtbot.addWidget(plot)
    line = LinkLine(0, 1, "registered", False, True, "stems", 0.4, 0.02, 5, "")
    scans = (
        ScanPlace("a.ply", np.zeros(2), 5, "registered"),
        ScanPlace("b.ply", np.ones(2), 5, "registered"),
    )
    found = PlotOutcome(
        tmp_path, ("a.ply", "b.ply"), (), scans, (line,), 0.01, (), None, 1.0
    )
    plot.open_scans(["a.ply", "b.ply"], tmp_path)
    plot._on_result(found)
    return plot, found


def test_a_link_is_left_out_of_the_next_run_until_taken_in(
    qtbot: QtBot, tmp_path: Path
) -> None:
    from amrst.review.pairs_file import write_pairs

    plot, _found = _one_link_shown(qtbot, tmp_path)
    plot.links.table.selectRow(0)
    by = plot.links.table.item(0, 5)
    assert by is not None
    plot.links.leave_button.click()
    assert plot.links.left_out == {(0, 1)}
    assert by.text() == "left out"
    assert plot.links.leave_button.text() == "Take in"
    # Point pairs for the link take it in again; leaving it out drops the pairs.
    pairs = tmp_path / "pairs.csv"
    write_pairs(pairs, np.eye(3), np.eye(3))
    plot.links.toggle_pairs(str(pairs))
    assert plot.links.left_out == set()
    assert by.text() == "your pairs"
    plot.links.leave_button.click()
    assert plot.links.hand_pairs == {}
    assert by.text() == "left out"
    plot.links.leave_button.click()
    assert plot.links.left_out == set()
    assert by.text() == "stems"


def test_closing_the_plot_window_asks_when_choices_were_not_run(
    qtbot: QtBot, tmp_path: Path, close_answers: list
) -> None:
    plot, found = _one_link_shown(qtbot, tmp_path)
    scans = found.scans
    plot.show()
    assert plot.pending_choices() == ""
    plot.links.table.selectRow(0)
    plot.links.leave_button.click()
    plot.scans.scan_list.setCurrentRow(1)
    plot.scans.set_scanner("1 2 0")
    assert plot.pending_choices() == "links left out, scanner positions"
    close_answers.append(False)
    assert not plot.close()
    assert plot.isVisible()
    assert plot.links.left_out == {(0, 1)}
    assert "links left out, scanner positions you chose" in close_answers.asked[0]
    assert plot.close()  # answered Close
    assert len(close_answers.asked) == 2
    plot.show()
    plot.links.leave_button.click()  # taken in again: only the scanner is not run
    assert plot.pending_choices() == "scanner positions"
    # Results opened whose run had a scanner given: that choice was run.
    given = (scans[0], dataclasses.replace(scans[1], given=(1.0, 2.0, 0.0)))
    plot._on_result(dataclasses.replace(found, scans=given), opened=True)
    assert plot.scans.given_scanners == {1: (1.0, 2.0, 0.0)}
    assert plot.pending_choices() == ""


def test_closing_the_app_asks_the_plot_window_first(
    make_main_window: Callable[..., MainWindow],
    plot_files: list[str],
    tmp_path: Path,
    close_answers: list,
) -> None:
    win = make_main_window()
    plot = win.open_plot(plot_files, tmp_path / "out")
    plot.scans.scan_list.setCurrentRow(1)
    plot.scans.set_scanner("1 2 0")
    close_answers.append(False)
    assert not win.close()
    assert win.isVisible()
    assert plot.isVisible()
    assert plot.scans.given_scanners == {1: (1.0, 2.0, 0.0)}
    assert win.close()
    assert len(close_answers.asked) == 2  # asked once more, not again by the window


def test_the_plot_run_leaves_out_the_links_the_window_names(
    plot_files: list[str], tmp_path: Path
) -> None:
    from amrst.plot.register import LEFT_OUT_ORIGIN
    from amrst.progress import NULL_REPORTER
    from amrst_gui.plot.jobs import run_plot

    o = run_plot(plot_files, tmp_path, False, NULL_REPORTER, left_out={(1, 0)})
    assert [ln.origin for ln in o.links] == [LEFT_OUT_ORIGIN]
    assert [s.status for s in o.scans] == ["registered", "failed"]
    assert o.missing == [plot_files[1]]


def test_a_plot_s_results_open_as_written_with_what_the_next_run_leaves_out(
    qtbot: QtBot,
    plot_files: list[str],
    tmp_path: Path,
    capsys: pytest.CaptureFixture[str],
) -> None:
    from amrst.plot.cli import main as plot_main
    from amrst_gui.plot.window import PlotWindow

    plot = PlotWindow()
    qtbot.addWidget(plot)
    plot.open_results(tmp_path)  # no plot there
    qtbot.waitUntil(lambda: not plot.busy, timeout=30_000)
    assert plot.outcome is None
    assert plot.status.text().startswith("Not opened:")
    assert "holds no plot" in plot.status.text()

    out = tmp_path / "out"
    args = [*plot_files, "--out", str(out), "--quiet", "--leave-out", "1", "2"]
    assert plot_main(args) == 3  # the command line's run: scan 2 not placed
    assert "the links left out cut it off" in capsys.readouterr().err
    with qtbot.waitSignal(plot.plot_done, timeout=30_000):
        plot.open_results(out)
    o = plot.outcome
    assert o is not None
    assert plot.links.left_out == {(0, 1)}
    assert plot.links.leave_button.text() == "Leave out"  # no link selected
    assert [s.status for s in o.scans] == ["registered", "failed"]
    assert o.scans[1].xy is None  # not placed
    assert len(o.trees) == len(STEMS)
    assert plot.trees.table.rowCount() == len(STEMS)
    assert plot.out_edit.text() == str(out)
    assert plot.scans.scan_list.count() == 2
    assert plot.scans.specs == [str(Path(f).resolve()) for f in plot_files]
    # Each tree from the side: its points, its height, its DBH.
    from amrst_gui.plot.tree import SIDE

    plot.select_tree(0)
    panel = plot.tree_panel
    panel.height_buttons.button(SIDE).click()
    assert panel.views.currentWidget() is panel.side_view
    assert panel.side_view.tree is o.trees[0]
    assert panel.side_view.profile is o.profiles[0]
    assert len(o.profiles[0].xyz) > 100
    assert not panel.side_view.grab().isNull()
    plot.select_tree(1)  # the choice holds from tree to tree
    assert panel.side_view.tree is o.trees[1]
    panel.height_buttons.button(1).click()
    assert panel.views.currentWidget() is panel.slice_view


def test_a_fixed_radius_plot_opens_with_its_edge_and_runs_again_with_it(
    qtbot: QtBot, plot_files: list[str], tmp_path: Path
) -> None:
    from amrst.plot.cli import main as plot_main
    from amrst.progress import NULL_REPORTER
    from amrst_gui.plot.jobs import run_plot
    from amrst_gui.plot.window import PlotWindow

    out = tmp_path / "out"
    args = [*plot_files, "--out", str(out), "--quiet", "--plot-radius", "6"]
    assert plot_main([*args, "--plot-centre", "1.5", "-2"]) == 0
    plot = PlotWindow()
    qtbot.addWidget(plot)
    with qtbot.waitSignal(plot.plot_done, timeout=30_000):
        plot.open_results(out)
    o = plot.outcome
    assert o is not None
    assert o.area is not None
    assert o.area.centre_xy == (1.5, -2.0)
    assert plot.area_row.radius_spin.value() == 6.0
    far = [np.hypot(t.xyz[0] - 1.5, t.xyz[1] + 2.0) > 6.0 for t in o.trees]
    assert sum(far) == 2  # of the six test stems
    for r, outside in enumerate(far):  # greyed in the table, and why
        assert ("outside the plot" in plot.trees.table.item(r, 0).toolTip()) == outside
    nbsp = "\u00a0"  # a unit stays on its number's line
    before = plot.status.text().split(": ")[-1].split(f"{nbsp}stems/ha")[0]
    assert f"Within 6{nbsp}m (0.0113{nbsp}ha): 4 trees, 4 with a DBH: " in (
        plot.status.text()
    )
    assert "m²/ha; 2 listed trees outside" in plot.status.text()
    k = far.index(False)
    plot.select_tree(k)
    plot.set_mark(o.trees[k].tree_id, "not a tree")  # one tree fewer per hectare
    after = plot.status.text().split(": ")[-1].split(f"{nbsp}stems/ha")[0]
    assert int(after) < int(before)
    assert not plot.stem_map.grab().isNull()  # the edge drawn with the trees
    assert plot.area_row.centre_edit.text() == "1.5 -2"
    plot.area_row.radius_spin.setValue(8.0)
    assert plot.area_row.area() == (8.0, (1.5, -2.0))  # the next run keeps the centre
    _area_applies_at_once(qtbot, plot, out)
    plot.area_row.centre_edit.setText("3, 4.25")
    assert plot.area_row.area() == (8.0, (3.0, 4.25))
    plot.area_row.centre_edit.setText("(512340.125, -2)")
    assert plot.area_row.area() == (8.0, (512340.125, -2.0))
    for text in ("12,5", "1,5 2", "3 north"):  # decimal commas are no pair
        plot.area_row.centre_edit.setText(text)
        with pytest.raises(InvalidInput):
            plot.area_row.area()
    plot.area_row.centre_edit.setText("")
    assert plot.area_row.area() == (8.0, None)  # the reference scanner
    plot.area_row.centre_edit.setText("3 north")
    plot.run()  # refused in a line, before anything is asked or run
    assert not plot.busy
    assert "Not run: the plot centre takes x and y" in plot.status.text()
    plot.area_row.centre_edit.setText("1e12 0")
    plot.run()
    assert "Not run: The plot centre must be two coordinates" in plot.status.text()
    plot.area_row.radius_spin.setValue(0.0)
    assert not plot.area_row.centre_edit.isEnabled()
    assert plot.area_row.area() is None
    assert plot.outcome is not None
    assert plot.outcome.area is None  # no plot radius any more
    assert json.loads((out / "plot.json").read_text())["plot_area"] is None
    assert set(_in_plot(out)) == {""}

    again = run_plot(
        plot_files, tmp_path / "again", False, NULL_REPORTER, area=(8.0, None)
    )
    assert again.area is not None
    assert (again.area.radius_m, again.area.centre_xy) == (8.0, (0.0, 0.0))


def _in_plot(out: Path) -> list[str]:
    from amrst.plot.export import TREES_CSV

    with (out / TREES_CSV).open() as fh:
        return [r["in_plot"] for r in csv.DictReader(fh)]


def _area_applies_at_once(qtbot: QtBot, plot: PlotWindow, out: Path) -> None:
    """A radius or centre changed applies to the plot shown, no run: its edge, the
    stand, plot.json and trees.csv; a centre clicked on the map; bad text refused."""
    from amrst.plot.stand import PlotArea

    o = plot.outcome
    assert o is not None
    area = PlotArea((1.5, -2.0), 8.0)
    assert o.area == area
    assert json.loads((out / "plot.json").read_text())["plot_area"] == area.as_dict()
    assert _in_plot(out) == ["yes" if area.holds(t.row()) else "no" for t in o.trees]
    assert "Within 8\u00a0m (0.0201\u00a0ha): " in plot.status.text()
    plot.area_row.centre_button.click()  # then a click on the map is the centre
    assert plot.stem_map.adding
    x, y = plot.stem_map.to_px(np.subtract((2.0, 1.0), o.reference_at))[0]
    QTest.mouseClick(
        plot.stem_map,
        Qt.MouseButton.LeftButton,
        Qt.KeyboardModifier.NoModifier,
        QPoint(round(x), round(y)),
    )
    assert not plot.stem_map.adding
    assert plot.outcome.area is not None
    assert np.allclose(plot.outcome.area.centre_xy, (2.0, 1.0), atol=0.1)
    cx, cy = (float(v) for v in plot.area_row.centre_edit.text().split())
    assert (cx, cy) == plot.outcome.area.centre_xy
    assert json.loads((out / "plot.json").read_text())["plot_area"]["centre_x_m"] == cx
    plot.area_row.centre_edit.setText("3 north")
    plot.area_row.centre_edit.editingFinished.emit()
    assert plot.status.text().startswith("Plot area not changed: the plot centre")
    assert plot.outcome.area.centre_xy == (cx, cy)
    plot.area_row.centre_edit.setText(f"{cx} {cy}")  # as it is: the stale refusal goes
    plot.area_row.centre_edit.editingFinished.emit()
    assert plot.status.text().startswith("The plot area is as shown")
    plot.area_row.centre_edit.setText("1.5 -2")
    plot.area_row.centre_edit.editingFinished.emit()
    assert plot.outcome.area == area


def test_a_review_file_that_cannot_be_read_is_never_written_over(
    qtbot: QtBot, plot_files: list[str], tmp_path: Path
) -> None:
    import json

    from amrst.plot.cli import main as plot_main
    from amrst.plot.review import REVIEW_JSON
    from amrst_gui.plot.window import PlotWindow

    out = tmp_path / "out"
    assert plot_main([*plot_files, "--out", str(out), "--quiet"]) == 0
    broken = '{"scans": [], "marks": {"T001": "OK"}}'  # typed by hand
    (out / REVIEW_JSON).write_text(broken)
    plot = PlotWindow()
    qtbot.addWidget(plot)
    with qtbot.waitSignal(plot.plot_done, timeout=30_000):
        plot.open_results(out)
    assert "Your review is not shown" in plot.status.text()
    plot.select_tree(0)
    plot.set_mark("T001", "check")
    assert "was not saved" in plot.status.text()
    assert (out / REVIEW_JSON).read_text() == broken
    plot.add_tree(50.0, 50.0)
    assert (out / REVIEW_JSON).read_text() == broken
    # A run's buttons: nothing that writes the folder while it runs.
    (out / REVIEW_JSON).write_text(json.dumps({"scans": [], "marks": {}}))
    plot.open_results(out)
    assert plot.busy  # opening is a job too: nothing that writes the folder meanwhile
    assert not plot.run_button.isEnabled()
    assert not plot.trees.add_button.isEnabled()
    qtbot.waitUntil(lambda: not plot.busy and plot.outcome is not None, timeout=30_000)
    plot.select_tree(1)
    assert plot.trees.table.selectedItems()
    plot.out_edit.setText(str(tmp_path / "again"))  # a new folder: nothing to ask
    plot.run()
    assert plot.busy
    # The run writes the review: no mark nor DBH is taken meanwhile (none lost).
    panel = plot.tree_panel
    assert panel.tree_id is not None
    for button in (
        plot.run_button,
        plot.trees.add_button,
        plot.trees.export_button,
        *panel.buttons.values(),
        panel.measure_button,
    ):
        assert not button.isEnabled()
    plot.shutdown()  # the window closes during the run
    assert plot.run_button.isEnabled()
    assert not plot.cancel_button.isEnabled()
    plot.open_scans([])  # no scans: nothing to run
    assert not plot.run_button.isEnabled()


def test_results_another_run_rewrote_are_not_written_over(
    qtbot: QtBot, plot_files: list[str], tmp_path: Path
) -> None:
    from amrst.files.folderlock import FolderLock
    from amrst.plot.cli import main as plot_main
    from amrst.plot.review import REVIEW_JSON
    from amrst_gui.plot.window import PlotWindow

    out = tmp_path / "out"
    assert plot_main([*plot_files, "--out", str(out), "--quiet"]) == 0
    plot = PlotWindow()
    qtbot.addWidget(plot)
    with qtbot.waitSignal(plot.plot_done, timeout=30_000):
        plot.open_results(out)
    plot.set_mark("T001", "ok")  # the window's own writes keep it the plot shown
    plot.area_row.radius_spin.setValue(40.0)
    plot.apply_area()
    with FolderLock(out):  # another writer holds the folder: said at once
        plot.set_mark("T002", "check")
    assert "trees.csv not: The folder" in plot.status.text()
    assert "being written by another AMRST run" in plot.status.text()
    assert read_review(out, plot_files).marks == {"T001": "ok", "T002": "check"}
    # Another run (the command line) writes its plot into the folder.
    assert plot_main([*plot_files, "--out", str(out), "--quiet", "--overwrite"]) == 0
    written = {f.name: f.read_bytes() for f in out.iterdir() if f.is_file()}
    plot.set_mark("T003", "ok")
    assert "changed since they were shown" in plot.status.text()
    plot.area_row.radius_spin.setValue(10.0)
    plot.apply_area()
    assert "changed since they were shown" in plot.status.text()
    assert {f.name: f.read_bytes() for f in out.iterdir() if f.is_file()} == written
    assert json.loads(written[REVIEW_JSON])["marks"] == {"T001": "ok", "T002": "check"}


def test_a_plot_json_with_a_link_that_cannot_be_is_not_opened(
    qtbot: QtBot, plot_files: list[str], tmp_path: Path
) -> None:
    import json

    from amrst.plot.cli import main as plot_main
    from amrst.plot.export import PLOT_JSON
    from amrst_gui.plot.window import PlotWindow

    out = tmp_path / "out"
    assert plot_main([*plot_files, "--out", str(out), "--quiet"]) == 0
    written = json.loads((out / PLOT_JSON).read_text())
    plot = PlotWindow()
    qtbot.addWidget(plot)
    # A link to no scan; a message that is no text; a pose of NaN.
    for key, value in (
        ("target", 7),
        ("message", 5),
        ("T_target_source", [[float("nan")] * 4] * 4),
    ):
        doc = json.loads(json.dumps(written))
        doc["links"][0][key] = value
        (out / PLOT_JSON).write_text(json.dumps(doc))
        plot.open_results(out)
        qtbot.waitUntil(lambda: not plot.busy, timeout=30_000)
        assert plot.outcome is None
        assert plot.status.text().startswith("Not opened:")
        assert "run the plot again" in plot.status.text()


def test_the_side_view_looks_across_a_top_that_stands_aside() -> None:
    from amrst_gui.plot.tree_side import across

    rng = np.random.default_rng(0)
    upright = np.column_stack([rng.normal(0, 0.1, (500, 2)), rng.uniform(0, 9, 500)])
    axis, seen = across(np.zeros(2), upright)
    assert np.allclose(axis, [1.0, 0.0])
    assert seen == "seen from the south"
    # Its top 3 m north of the foot: seen from the south the lean would not show.
    stray = np.vstack([upright, [[3.0, 0.0, 9.3]]])  # one point does not turn it
    assert np.allclose(across(np.zeros(2), stray)[0], [1.0, 0.0])
    top = np.column_stack([rng.normal(0, 0.1, 50), rng.normal(3, 0.1, 50), [9.5] * 50])
    axis, seen = across(np.zeros(2), np.vstack([upright, top]))
    assert np.allclose(axis, [0.0, 1.0], atol=0.1)
    assert seen == "seen with its top to the right"


def test_a_placed_scan_whose_scanner_is_not_known_says_so() -> None:
    from amrst_gui.plot.jobs import PlotOutcome, ScanPlace
    from amrst_gui.plot.tables import scan_lines

    scans = (
        ScanPlace("a.laz", np.zeros(2), 5, "registered"),
        ScanPlace("b.laz", None, 4, "registered"),  # georeferenced, no scanner
        ScanPlace("c.laz", None, 3, "failed", None),
    )
    o = PlotOutcome(Path("."), ("a", "b", "c"), (), scans, (), 0.01, (), None, 1.0)
    lines = [whole for _listed, whole in scan_lines(o)]
    assert "placed (the file does not say where its scanner stood)" in lines[1]
    assert "not placed" in lines[2]
    assert not any("residual" in line for line in lines)  # none known


def test_a_long_scan_name_is_cut_in_the_middle_in_the_list() -> None:
    from amrst_gui.plot.tables import LIST_NAME_CHARS, scan_title

    long = "/d/Forest_Reserve_plot_0412_2026-11-30_FARO_Focus_S350_position_12.ply"
    short = scan_title(long, "", short=True)
    assert len(short) == LIST_NAME_CHARS
    assert short.startswith("Forest_Reserve")
    assert short.endswith("position_12.ply")  # the end that tells scans apart
    assert scan_title(long, "") == Path(long).name  # messages keep it whole
    assert scan_title("/d/scan_1.ply", "S1", short=True) == "scan_1.ply (S1)"


def test_another_scan_is_made_the_reference_before_a_run(
    qtbot: QtBot, plot_files: list[str]
) -> None:
    from amrst_gui.plot.window import PlotWindow

    plot = PlotWindow()
    qtbot.addWidget(plot)
    plot.open_scans(plot_files)
    assert not plot.scans.reference_button.isEnabled()  # S1 is the reference already
    plot.scans.scan_list.setCurrentRow(1)
    plot.scans.set_scanner("1 2 3")  # goes with its scan
    assert plot.scans.reference_button.isEnabled()
    plot.scans.reference_button.click()
    assert plot.scans.specs == [str(Path(f).resolve()) for f in reversed(plot_files)]
    item = plot.scans.scan_list.item(0)
    assert item is not None
    assert item.text() == "S1  scan_2.ply; scanner given"
    assert "1.00, 2.00, 3.00" in item.toolTip()
    assert "scan_2.ply is the reference now" in plot.status.text()
    assert plot.scans.given_scanners == {0: (1.0, 2.0, 3.0)}


_REGISTERED = json.dumps({"target_file": "/scans/t.ply", "source_file": "/scans/s.ply"})


@pytest.mark.parametrize(
    ("name", "text", "question", "beside"),
    [
        # an earlier run's list, its plot.json lost: replaced when asked
        ("trees.csv", "an earlier run's list\n", "holds trees.csv but no plot", False),
        # amrst register's result: the plot goes beside it when asked
        ("transform.json", _REGISTERED, "holds the export of s.ply onto t.ply", True),
    ],
)
def test_a_folder_of_another_runs_files_takes_a_run_only_when_asked(
    qtbot: QtBot,
    plot_files: list[str],
    tmp_path: Path,
    monkeypatch: pytest.MonkeyPatch,
    name: str,
    text: str,
    question: str,
    beside: bool,
) -> None:
    from amrst_gui.plot import window as plot_window

    out = tmp_path / "out"
    out.mkdir()
    (out / name).write_text(text)
    answers = [False, True]
    asked: list[str] = []

    def answer(_parent: object, title: str, text: str) -> bool:
        asked.append(f"{title} {text}")
        return answers.pop(0)

    monkeypatch.setattr(plot_window, "confirm", answer)
    plot = plot_window.PlotWindow()
    qtbot.addWidget(plot)
    plot.open_scans(plot_files, out)
    plot.run()  # asked, and kept
    assert question in asked[0]
    assert not plot.busy
    assert "is kept as it is" in plot.status.text()
    assert (out / name).read_text() == text
    assert not (out / "plot.json").exists()
    _run(qtbot, plot)  # asked again, and run: no dead end
    assert len(asked) == 2
    assert plot.outcome is not None
    assert (out / "plot.json").is_file()
    assert ((out / name).read_text() == text) == beside


def test_a_scan_is_removed_from_the_plot_and_two_stay(
    qtbot: QtBot, plot_files: list[str], tmp_path: Path
) -> None:
    import shutil

    from amrst_gui.plot.window import PlotWindow

    third = tmp_path / "scan_3.ply"
    shutil.copyfile(plot_files[1], third)
    plot = PlotWindow()
    qtbot.addWidget(plot)
    plot.open_scans([*plot_files, str(third)])
    plot.scans.scan_list.setCurrentRow(2)
    plot.scans.set_scanner("1 2 3")  # scan 3's position goes with it
    plot.scans.scan_list.setCurrentRow(1)
    assert plot.scans.remove_button.isEnabled()
    plot.scans.remove_button.click()
    assert plot.scans.specs == [
        str(Path(plot_files[0]).resolve()),
        str(third.resolve()),
    ]
    assert plot.scans.given_scanners == {1: (1.0, 2.0, 3.0)}
    assert plot.status.text().startswith("scan_2.ply is left out: 2 scans.")
    plot.scans.scan_list.setCurrentRow(0)
    assert not plot.scans.remove_button.isEnabled()  # a plot needs two
    plot.scans.remove_scan()
    assert len(plot.scans.specs) == 2
    # The reference may go too: the next scan becomes S1.
    plot.open_scans([*plot_files, str(third)])
    plot.scans.scan_list.setCurrentRow(0)
    plot.scans.remove_button.click()
    assert plot.scans.specs[0] == str(Path(plot_files[1]).resolve())
    assert "scan_2.ply is the reference now (S1)" in plot.status.text()


def test_marks_hold_when_a_scan_is_removed_and_the_plot_run_again(
    qtbot: QtBot,
    plot_files: list[str],
    tmp_path: Path,
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    from amrst import io
    from amrst_gui.plot import window as plot_window
    from amrst_gui.plot.window import PlotWindow

    third = tmp_path / "scan_3.ply"  # a third position, in the reference's frame
    io.write(third, Cloud(scan((1.0, -6.0), STEMS, 3)))
    out = tmp_path / "out"
    plot = PlotWindow()
    qtbot.addWidget(plot)
    plot.open_scans([*plot_files, str(third)], out)
    _run(qtbot, plot)
    marks = {
        plot.outcome.trees[0].tree_id: "ok",
        plot.outcome.trees[1].tree_id: "check",
    }
    for tree_id, mark in marks.items():
        plot.set_mark(tree_id, mark)
    asked: list[str] = []
    monkeypatch.setattr(
        plot_window, "confirm", lambda _p, _t, text: asked.append(text) or True
    )
    plot.select_tree(1)
    shown = plot.tree_panel.tree_id
    _run(qtbot, plot)  # the same scans again: the tree shown stays shown
    assert "a plot of these scans" in asked[0]
    assert plot.stem_map.selected is not None
    assert plot.tree_panel.tree_id == shown
    plot.scans.scan_list.setCurrentRow(2)
    plot.scans.remove_button.click()
    _run(qtbot, plot)
    assert "same reference with other scans" in asked[1]
    assert plot.review.marks == marks  # shown, and kept by the next mark
    plot.set_mark(plot.outcome.trees[2].tree_id, "ok")
    assert len(read_review(out, plot.outcome.labels).marks) == 3


def test_results_whose_scan_was_moved_open_and_say_so(
    qtbot: QtBot, plot_files: list[str], tmp_path: Path
) -> None:
    import shutil

    from amrst.plot.cli import main as plot_main
    from amrst_gui.plot.window import PlotWindow

    scans = [tmp_path / Path(f).name for f in plot_files]
    for f, copy in zip(plot_files, scans, strict=True):
        shutil.copyfile(f, copy)
    out = tmp_path / "out"
    assert plot_main([*map(str, scans), "--out", str(out), "--quiet"]) == 0
    scans[1].rename(tmp_path / "elsewhere.ply")
    plot = PlotWindow()
    qtbot.addWidget(plot)
    with qtbot.waitSignal(plot.plot_done, timeout=30_000):
        plot.open_results(out)
    item = plot.scans.scan_list.item(1)
    assert item is not None
    assert "scan_2.ply (file missing)" in item.text()
    assert "Not where plot.json says: S2 (scan_2.ply)" in plot.status.text()
    assert plot.outcome is not None
    assert len(plot.outcome.trees) == len(STEMS)  # shown from its results
    # Opened again from where it is now, it is the same plot: a run keeps the marks.
    from amrst_gui.plot.jobs import SAME_REFERENCE, SAME_SCANS, same_plot

    assert (
        same_plot(out, [str(scans[0]), str(tmp_path / "elsewhere.ply")]) == SAME_SCANS
    )
    assert same_plot(out, [str(scans[0]), str(scans[0])]) == SAME_REFERENCE
    assert same_plot(out, [str(tmp_path / "elsewhere.ply"), str(scans[0])]) == ""


def test_a_plot_whose_plot_json_is_lost_is_known_by_its_review(
    plot_files: list[str], tmp_path: Path
) -> None:
    import os

    from amrst.plot.review import PlotReview, write_review
    from amrst_gui.plot.jobs import SAME_SCANS, same_plot

    out = tmp_path / "out"
    out.mkdir()
    labels = [str(Path(f).resolve()) for f in plot_files]
    write_review(out, labels, PlotReview(marks={"T001": "ok"}))
    (out / "plot.json").write_text('{"scans": [')  # cut short
    assert same_plot(out, labels) == SAME_SCANS  # a run of these keeps the marks
    assert not same_plot(out, labels[::-1])
    (out / "plot.json").unlink()
    os.mkfifo(out / "plot.json")  # read on the GUI thread: never blocks it
    assert same_plot(out, labels) == SAME_SCANS


def test_other_scans_opened_leave_the_last_plot_s_results_folder(
    qtbot: QtBot, tmp_path: Path
) -> None:
    from amrst.plot.export import PLOT_CLOUD

    (tmp_path / PLOT_CLOUD).write_bytes(b"")
    plot, _found = _one_link_shown(qtbot, tmp_path)
    assert plot.out_edit.text() == str(tmp_path)
    assert plot.cloud_check.isChecked()
    plot.open_scans(["c.ply", "d.ply"])  # File ▸ Open plot… gives no folder
    assert plot.out_edit.text() == ""  # Run asks for one
    assert not plot.cloud_check.isChecked()


def test_closing_the_plot_window_during_a_run_asks_first(
    qtbot: QtBot, plot_files: list[str], tmp_path: Path, close_answers: list
) -> None:
    from amrst.plot.export import PLOT_JSON
    from amrst_gui.plot.window import PlotWindow

    plot = PlotWindow()
    qtbot.addWidget(plot)
    plot.show()
    out = tmp_path / "out"
    plot.open_scans(plot_files, out)
    plot.run()
    assert plot.busy
    close_answers.append(False)  # Cancel: the run goes on
    assert not plot.close()
    assert plot.isVisible()
    assert plot.busy
    assert close_answers.asked == [
        "A plot is running: closing the window cancels it. Close it anyway?"
    ]
    assert plot.close()  # Close: the run is cancelled
    assert not plot.busy
    qtbot.wait(500)
    assert not (out / PLOT_JSON).exists()


def test_a_dbh_measured_and_not_kept_is_asked_about_before_it_goes(
    qtbot: QtBot,
    plot_run: Path,
    tmp_path: Path,
    discard_answers: list,
    close_answers: list,
) -> None:
    from amrst_gui.plot.tables import row_of_tree

    plot, _out = _shown(qtbot, plot_run, tmp_path)
    o = plot.outcome
    assert o is not None
    plot.select_tree(0)
    panel, tree = plot.tree_panel, o.trees[0]
    view = panel.slice_view
    panel.measure_button.click()
    a = np.radians([200.0, 250.0, 300.0, 330.0])
    r = tree.stem.dbh_m / 2
    rim = np.asarray(tree.stem.dbh_xy) + r * np.column_stack([np.cos(a), np.sin(a)])
    for x, y in view.to_px(rim):
        QTest.mouseClick(
            view, Qt.MouseButton.LeftButton, pos=QPoint(round(x), round(y))
        )
    assert panel.keep_button.isEnabled()
    # N, a click on another tree on the map, another row: each asked, each refused.
    for choose in (
        lambda: plot.step_tree(1),
        lambda: plot.stem_map.tree_clicked.emit(1),
        lambda: plot.trees.table.selectRow(row_of_tree(plot.trees.table, 1)),
    ):
        discard_answers.append(False)
        choose()
        assert panel.tree_id == tree.tree_id
        assert len(view.clicks) == 4
        assert plot.trees.table.currentRow() == row_of_tree(plot.trees.table, 0)
    assert discard_answers.asked == ["Choosing another tree"] * 3
    plot.set_mark(tree.tree_id, "check")  # a mark given meanwhile keeps the points
    assert len(view.clicks) == 4
    assert view.measuring
    plot.out_edit.setText(str(tmp_path / "again"))  # a new folder: nothing else asked
    discard_answers.append(False)
    plot.run()  # refused: not run, the points stay
    assert not plot.busy
    assert discard_answers.asked[-1] == "Running the plot"
    assert len(view.clicks) == 4
    close_answers.append(False)
    assert not plot.close()
    assert (
        f"Closing the window drops your DBH of {tree.tree_id} measured and not kept "
        "(4 points; Keep DBH keeps it)." in close_answers.asked[0]
    )
    assert len(view.clicks) == 4
    plot.step_tree(1)  # Discard: the next tree
    assert panel.tree_id != tree.tree_id
    assert not view.measuring
    assert plot.close()  # nothing left to ask about
    assert len(close_answers.asked) == 1


def test_opening_another_plot_asks_before_it_drops_choices_not_run(
    make_main_window: Callable[..., MainWindow],
    qtbot: QtBot,
    plot_files: list[str],
    tmp_path: Path,
    discard_answers: list,
    close_answers: list,
) -> None:
    win = make_main_window()
    plot = win.open_plot(plot_files, tmp_path / "out")
    plot.scans.scan_list.setCurrentRow(1)
    plot.scans.set_scanner("1 2 0")
    specs = list(plot.scans.specs)
    discard_answers.append(False)  # Cancel: the plot shown stays
    assert win.open_plot(plot_files[::-1]) is plot
    discard_answers.append(False)
    win.open_plot_results(tmp_path / "elsewhere")
    assert not plot.busy
    assert plot.scans.specs == specs
    assert plot.scans.given_scanners == {1: (1.0, 2.0, 0.0)}
    assert discard_answers.asked == ["Opening another plot"] * 2
    win.open_plot_results(tmp_path / "elsewhere")  # Discard
    qtbot.waitUntil(lambda: not plot.busy, timeout=30_000)
    assert plot.scans.given_scanners == {}
    assert plot.status.text().startswith("Not opened:")
    assert len(discard_answers.asked) == 3
    # Closed with a choice not run (asked then), the window opens another at once.
    plot.open_scans(plot_files)
    plot.scans.scan_list.setCurrentRow(1)
    plot.scans.set_scanner("1 2 0")
    assert plot.close()
    assert close_answers.asked
    win.open_plot(plot_files)
    assert plot.isVisible()
    assert plot.scans.given_scanners == {}
    assert len(discard_answers.asked) == 3


def test_tab_reaches_the_buttons_past_the_links_and_trees_tables(
    qtbot: QtBot, plot_run: Path, tmp_path: Path
) -> None:
    plot, _out = _shown(qtbot, plot_run, tmp_path)
    plot.links.table.selectRow(0)  # Open pair and Leave out take it
    plot.links.table.setFocus()
    visited = []
    for _ in range(40):
        widget = plot.focusWidget()
        visited.append(widget)
        QTest.keyClick(widget, Qt.Key.Key_Tab)
    for button in (
        plot.links.open_button,
        plot.links.leave_button,
        plot.trees.add_button,
        plot.trees.report_button,
        plot.trees.export_button,
    ):
        assert button in visited, button.text()
    assert plot.trees.table in visited
    # The arrows still move from row to row.
    plot.trees.table.setFocus()
    plot.trees.table.setCurrentCell(0, 0)
    QTest.keyClick(plot.trees.table, Qt.Key.Key_Down)
    assert plot.trees.table.currentRow() == 1


def test_other_scans_opened_take_no_plot_area_of_the_last_plot(
    qtbot: QtBot, plot_files: list[str], tmp_path: Path
) -> None:
    from amrst_gui.plot.window import PlotWindow

    plot = PlotWindow()
    qtbot.addWidget(plot)
    plot.open_scans(["a.ply", "b.ply"])
    plot.area_row.radius_spin.setValue(12.0)
    plot.area_row.centre_edit.setText("5 5")
    plot.open_scans(plot_files, tmp_path)  # another plot: no radius of the last
    assert plot.area_row.radius_spin.value() == 0.0
    assert plot.area_row.centre_edit.text() == ""
    assert plot.area_row.area() is None
    # Another reference, or a scan left out, is the same plot: its area holds.
    plot.open_scans(["a.ply", "b.ply", "c.ply"], tmp_path)
    plot.area_row.radius_spin.setValue(12.0)
    plot.area_row.centre_edit.setText("5 5")
    plot.scans.scan_list.setCurrentRow(1)
    plot.scans.make_reference()
    plot.scans.scan_list.setCurrentRow(2)
    plot.scans.remove_scan()
    assert [Path(s).name for s in plot.scans.specs] == ["b.ply", "a.ply"]
    assert plot.area_row.area() == (12.0, (5.0, 5.0))
    assert plot.out_edit.text() == str(tmp_path)


def test_the_plot_area_is_not_typed_while_a_run_would_drop_it(
    qtbot: QtBot, plot_files: list[str], tmp_path: Path
) -> None:
    from amrst_gui.plot.window import PlotWindow

    plot = PlotWindow()
    qtbot.addWidget(plot)
    plot.open_scans(plot_files, tmp_path / "out")
    plot.area_row.radius_spin.setValue(12.0)
    plot.area_row.centre_button.setChecked(True)
    plot.run()
    assert plot.busy
    for widget in (
        plot.area_row.radius_spin,
        plot.area_row.centre_edit,
        plot.area_row.centre_button,
    ):
        assert not widget.isEnabled()
    assert not plot.area_row.centre_button.isChecked()  # no click on the map awaited
    plot.cancel()
    qtbot.waitUntil(lambda: not plot.busy, timeout=10_000)
    for widget in (
        plot.area_row.radius_spin,
        plot.area_row.centre_edit,
        plot.area_row.centre_button,
    ):
        assert widget.isEnabled()
    assert plot.area_row.radius_spin.value() == 12.0  # the next run's


def test_a_plot_area_not_saved_goes_back_to_the_one_in_force(
    qtbot: QtBot, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    from amrst.plot import export

    def refused(out: Path, *_args: Any) -> None:
        raise PermissionError(f"[Errno 13] Permission denied: '{out}'")

    plot, _found = _one_link_shown(qtbot, tmp_path)
    monkeypatch.setattr(export, "write_area", refused)
    plot.area_row.radius_spin.setValue(12.0)
    assert plot.status.text().startswith("Plot area not changed: [Errno 13]")
    assert plot.area_row.radius_spin.value() == 0.0  # no radius, as the map shows
    assert plot.found is not None
    assert plot.found.area is None


def test_scans_opened_into_a_folder_of_their_results_show_them(
    qtbot: QtBot, plot_files: list[str], plot_run: Path, tmp_path: Path
) -> None:
    import shutil

    from amrst_gui.plot.window import PlotWindow

    out = tmp_path / "out"
    shutil.copytree(plot_run, out)
    plot = PlotWindow()
    qtbot.addWidget(plot)
    with qtbot.waitSignal(plot.plot_done, timeout=30_000):
        plot.open_scans(plot_files, out)  # File ▸ Open plot… with a folder
    assert plot.outcome is not None
    assert plot.trees.table.rowCount() == len(STEMS)
    assert plot.scans.specs == [str(Path(f).resolve()) for f in plot_files]
    assert f"opened from {out}" in plot.status.text()
    assert plot.run_button.isEnabled()
    # Another folder, or other scans, show nothing until they are run.
    plot.open_scans(plot_files, tmp_path / "new")
    assert plot.outcome is None
    assert not plot.busy
    plot.open_scans(plot_files[::-1], out)
    assert plot.outcome is None
    assert not plot.busy


def test_an_opening_of_results_is_not_called_a_run(
    qtbot: QtBot, plot_run: Path, tmp_path: Path
) -> None:
    from amrst_gui.plot.window import PlotWindow

    plot = PlotWindow()
    qtbot.addWidget(plot)
    assert plot.open_results(plot_run)
    assert not plot.open_results(plot_run)
    assert plot.status.text() == "A plot is being opened: wait, or cancel it."
    plot.cancel()
    qtbot.waitUntil(lambda: not plot.busy, timeout=10_000)
    assert plot.status.text() == "Opening cancelled."
    assert plot.outcome is None
    assert plot.windowTitle() == "AMRST Studio: plot"  # not "plot in" the folder


def test_scans_of_one_name_are_told_apart_by_their_number(
    qtbot: QtBot, tmp_path: Path
) -> None:
    from amrst_gui.plot.jobs import PlotOutcome, ScanPlace
    from amrst_gui.plot.window import PlotWindow

    labels = [str(tmp_path / d / "source.ply") for d in ("a", "b", "c")]
    scans = (
        ScanPlace(labels[0], np.zeros(2), 5, "registered"),
        ScanPlace(labels[1], None, 5, "needs review"),
        ScanPlace(labels[2], None, 0, "failed"),
    )
    found = PlotOutcome(tmp_path, tuple(labels), (), scans, (), 0.01, (), None, 1.0)
    plot = PlotWindow()
    qtbot.addWidget(plot)
    plot.open_scans(labels, tmp_path)
    plot._on_result(found)
    text = plot.status.text()
    assert "Needs review: S2 (source.ply) (check its links" in text
    assert "Not placed: S3 (source.ply) (select its link" in text
    assert "Not where plot.json says: S1 (source.ply), S2 (source.ply), S3" in text


def test_a_trees_csv_a_spreadsheet_saved_again_opens_or_says_why_not(
    qtbot: QtBot, plot_run: Path, tmp_path: Path
) -> None:
    from amrst.plot.export import TREES_CSV
    from amrst.plot.view import VIEW_NPZ

    plot, out = _shown(qtbot, plot_run, tmp_path)
    csv_path = out / TREES_CSV
    text = csv_path.read_text(encoding="utf-8")
    # Excel's UTF-8 CSV: a byte-order mark and CRLF line ends.
    csv_path.write_bytes(b"\xef\xbb\xbf" + text.replace("\n", "\r\n").encode())
    with qtbot.waitSignal(plot.plot_done, timeout=30_000):
        plot.open_results(out)
    assert plot.trees.table.rowCount() == len(STEMS)
    # Saved with ';' between the columns, or in another encoding: said so.
    for damaged, why in (
        (text.replace(",", ";").encode(), "has no tree_id column"),
        (text.replace("T001", "T\u00e9").encode("latin-1"), "is not UTF-8 text"),
    ):
        csv_path.write_bytes(damaged)
        plot.open_results(out)
        qtbot.waitUntil(lambda: not plot.busy, timeout=30_000)
        assert plot.outcome is None
        assert plot.status.text() == (
            f"Not opened: {out} holds no readable plot (trees.csv {why}: another "
            "program saved it over): run the plot again from its scans."
        )
    (out / VIEW_NPZ).unlink()
    plot.open_results(out)
    qtbot.waitUntil(lambda: not plot.busy, timeout=30_000)
    assert plot.status.text() == (
        f"Not opened: {out} holds a plot, but its view.npz (the drawing of its "
        "trees) is missing: run the plot again from its scans."
    )


def test_a_results_folder_that_is_a_file_is_refused_in_the_app_s_words(
    qtbot: QtBot, plot_files: list[str], tmp_path: Path
) -> None:
    from amrst_gui.plot.window import PlotWindow

    out = tmp_path / "results"
    out.write_text("")
    plot = PlotWindow()
    qtbot.addWidget(plot)
    plot.open_scans(plot_files, out)
    plot.run()
    qtbot.waitUntil(lambda: not plot.busy, timeout=60_000)
    assert plot.status.text() == (
        f"The plot failed: {out} is a file, not a folder: choose another results "
        "folder."
    )


def test_a_plot_whose_engine_process_stops_says_to_run_it_again(
    qtbot: QtBot, plot_files: list[str], tmp_path: Path
) -> None:
    import os
    import signal

    from amrst_gui.engine_process import ENGINE
    from amrst_gui.plot.window import PlotWindow

    plot = PlotWindow()
    qtbot.addWidget(plot)
    plot.open_scans(plot_files, tmp_path / "out")
    plot.run()
    qtbot.waitUntil(
        lambda: plot.status.text().startswith("Running: ") and ENGINE.pid is not None,
        timeout=30_000,
    )
    pid = ENGINE.pid
    assert pid is not None
    os.kill(pid, signal.SIGKILL)  # as the system does when memory runs out
    qtbot.waitUntil(lambda: not plot.busy, timeout=30_000)
    text = plot.status.text()
    assert text == (
        "The plot failed: The engine process stopped (killed by signal 9) before the "
        "work was done. Run it again; if it stops again, close other programs to "
        "free memory."
    )
    assert plot.run_button.isEnabled()


def test_a_results_folder_typed_as_a_name_is_made_beside_the_scans(
    qtbot: QtBot,
    plot_files: list[str],
    tmp_path: Path,
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    import shutil

    from amrst_gui.plot.window import PlotWindow

    monkeypatch.chdir(tmp_path)  # where the app was started: not the place
    plot = PlotWindow()
    qtbot.addWidget(plot)
    plot.open_scans(plot_files)
    plot.out_edit.setText("results_typed")
    out = Path(plot_files[0]).resolve().parent / "results_typed"
    try:
        _run(qtbot, plot)
        assert (out / "plot.json").is_file()
        assert not (tmp_path / "results_typed").exists()
        assert plot.out_edit.text() == str(out)
        assert f"written to {out}" in plot.status.text()
    finally:
        shutil.rmtree(out, ignore_errors=True)
    # Given as a name to open, it is the working directory's, said in full.
    plot.open_results(Path("elsewhere"))
    qtbot.waitUntil(lambda: not plot.busy, timeout=30_000)
    assert plot.status.text().startswith(f"Not opened: {tmp_path / 'elsewhere'} ")
    assert plot.windowTitle() == "AMRST Studio: plot"  # not "plot in elsewhere"


def test_a_tree_without_a_crown_width_shows_a_dash() -> None:
    from amrst.plot.review import PlotReview
    from amrst_gui.plot.tree import figures

    tree = _tree("H001", (1,))
    assert dict(figures(tree, PlotReview()))["Crown"] == "6.00 m wide"
    stem = dataclasses.replace(tree.stem, crown_width_m=float("nan"))
    bare = dataclasses.replace(tree, stem=stem)  # added by hand, no points found
    assert dict(figures(bare, PlotReview()))["Crown"] == "–"
    # A DBH to check says which of its checks failed.
    assert "why" not in dict(figures(tree, PlotReview()))["DBH fit"]
    doubt = dataclasses.replace(tree.stem, dbh_quality="check", dbh_why="a reason")
    fit = dict(figures(dataclasses.replace(tree, stem=doubt), PlotReview()))["DBH fit"]
    assert fit.endswith("\nwhy check: a reason")


def test_a_scan_opened_through_a_link_keeps_the_name_given(
    qtbot: QtBot, plot_files: list[str], tmp_path: Path
) -> None:
    from amrst_gui.plot.window import PlotWindow

    link = tmp_path / "stand7_pos1.ply"
    link.symlink_to(plot_files[0])
    plot = PlotWindow()
    qtbot.addWidget(plot)
    plot.open_scans([str(link), plot_files[1]])
    assert plot.scans.specs[0] == str(link)
    assert "stand7_pos1.ply" in plot.scans.scan_list.item(0).text()


def test_trees_without_a_dbh_end_the_table_whichever_way_it_is_sorted(
    qtbot: QtBot, tmp_path: Path
) -> None:
    from dataclasses import replace

    from amrst.plot.review import PlotReview
    from amrst_gui.plot.jobs import PlotOutcome
    from amrst_gui.plot.tables import TREE_COLUMNS, fill_trees, table, tree_at_row

    trees = [_tree("T001", (1,)), _tree("T002", (1,)), _tree("T003", (1,))]
    trees[0] = replace(trees[0], stem=replace(trees[0].stem, dbh_m=float("nan")))
    trees[2] = replace(trees[2], stem=replace(trees[2].stem, dbh_m=0.5))
    o = PlotOutcome(tmp_path, ("a.ply",), tuple(trees), (), (), 0.01, (), None, 1.0)
    view = table(TREE_COLUMNS, "plot_trees")
    qtbot.addWidget(view)
    fill_trees(view, o, PlotReview())
    for order, ids in (
        (Qt.SortOrder.AscendingOrder, ["T002", "T003", "T001"]),
        (Qt.SortOrder.DescendingOrder, ["T003", "T002", "T001"]),
    ):
        view.sortByColumn(1, order)
        assert [o.trees[tree_at_row(view, r)].tree_id for r in range(3)] == ids


def test_scans_picked_are_ordered_by_name_numbers_by_value(
    qtbot: QtBot, monkeypatch: pytest.MonkeyPatch, tmp_path: Path
) -> None:
    from PySide6.QtCore import QSettings
    from PySide6.QtWidgets import QWidget

    from amrst_gui.plot import window as plot_window

    picked = [f"/plot/Scan_{k}.e57" for k in (10, 2, 1)] + ["/plot/scan_3.e57"]
    monkeypatch.setattr(
        plot_window.QFileDialog, "getOpenFileNames", lambda *_a: (picked, "")
    )
    parent = QWidget()
    qtbot.addWidget(parent)
    settings = QSettings(str(tmp_path / "s.ini"), QSettings.Format.IniFormat)
    assert plot_window.ask_scans(parent, settings) == [
        "/plot/Scan_1.e57",
        "/plot/Scan_2.e57",
        "/plot/scan_3.e57",
        "/plot/Scan_10.e57",
    ]


def test_the_menus_click_the_buttons_and_show_their_state(
    qtbot: QtBot, plot_files: list[str], tmp_path: Path
) -> None:
    from amrst_gui.plot import window as plot_window

    plot = plot_window.PlotWindow()
    qtbot.addWidget(plot)
    plot.open_scans(plot_files, tmp_path / "out")
    menus = {m.title().replace("&", ""): m for m in plot.menuBar().findChildren(QMenu)}
    assert {"Plot", "Scans", "Links", "Trees"} <= set(menus)

    def item(menu: str, text: str) -> QAction:
        menus[menu].aboutToShow.emit()  # as the menu opens
        return next(a for a in menus[menu].actions() if a.text().split("\t")[0] == text)

    assert not item("Plot", "Export inventory…").isEnabled()  # nothing to export
    assert item("Plot", "Run plot").text() == "Run plot\tCtrl+R"
    with qtbot.waitSignal(plot.plot_done, timeout=300_000):
        item("Plot", "Run plot").trigger()
    assert plot.outcome is not None
    assert item("Plot", "Export inventory…").isEnabled()
    plot.select_tree(0)
    item("Trees", "Mark check").trigger()
    assert plot.review.marks == {plot.outcome.trees[0].tree_id: "check"}
    item("Trees", "Next tree").trigger()
    assert plot.tree_panel.tree_id == plot.outcome.trees[1].tree_id
    assert not item("Links", "Accept").isEnabled()  # its link is registered
    plot.links.table.selectRow(0)
    item("Links", "Leave out").trigger()
    assert plot.links.left_out == {(0, 1)}
    item("Links", "Take in").trigger()  # the button's text, followed
    assert plot.links.left_out == set()
