"""Spreadsheets of the campaign table and the plot inventory: header, rows, frozen."""

from __future__ import annotations

import pytest

from amrst.files.atomic import write_atomic, xlsx_book


def test_a_table_round_trips_through_xlsx(tmp_path) -> None:
    openpyxl = pytest.importorskip("openpyxl")
    rows = [{"tree_id": "T1", "dbh_m": 0.31}, {"tree_id": "T2", "dbh_m": ""}]
    book = xlsx_book("trees", ("tree_id", "dbh_m"), rows, "AMRST test")
    assert book is not None
    path = tmp_path / "trees.xlsx"
    write_atomic(path, lambda tmp: book.save(tmp))
    read = openpyxl.load_workbook(path)
    assert read.properties.creator == "AMRST test"
    sheet = read["trees"]
    values = [[c.value for c in r] for r in sheet.iter_rows()]
    assert values == [["tree_id", "dbh_m"], ["T1", 0.31], ["T2", None]]
    assert sheet.freeze_panes == "B2"
