"""Point-pair files: round trip, and one-line messages for bad files."""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np
import pytest

from amrst.errors import InvalidInput
from amrst.review.pairs_file import COLUMNS, read_pairs, write_pairs

if TYPE_CHECKING:
    from pathlib import Path


def test_pairs_round_trip(tmp_path: Path) -> None:
    rng = np.random.default_rng(0)
    t = rng.normal(size=(6, 3)) * 10 + 5e5
    s = rng.normal(size=(6, 3))
    path = tmp_path / "pairs.csv"
    write_pairs(path, t, s)
    assert path.read_text().splitlines()[0] == ",".join(COLUMNS)
    t2, s2 = read_pairs(path)
    np.testing.assert_allclose(t2, t, atol=1e-6)
    np.testing.assert_allclose(s2, s, atol=1e-6)


def test_extra_columns_and_spaces_are_fine(tmp_path: Path) -> None:
    path = tmp_path / "pairs.csv"
    path.write_text(
        "label, target_x,target_y,target_z,source_x,source_y,source_z\n"
        "a, 1,2,3, 4,5,6\nb,7,8,9,10,11,12\n"
    )
    t, s = read_pairs(path)
    assert t.tolist() == [[1, 2, 3], [7, 8, 9]]
    assert s.tolist() == [[4, 5, 6], [10, 11, 12]]


@pytest.mark.parametrize(
    ("text", "words"),
    [
        ("x,y,z\n1,2,3\n", "no column"),
        (",".join(COLUMNS) + "\n1,2,3,4,5,nan\n1,2,3,4,5,6\n", "line 2"),
        (",".join(COLUMNS) + "\n1,2,3,4,5,abc\n1,2,3,4,5,6\n", "not a coordinate"),
        (",".join(COLUMNS) + "\n1,2,3,4,5,1e300\n1,2,3,4,5,6\n", "within 1e9 m"),
        (",".join(COLUMNS) + "\n1,2,3,4,5,6\n", "at least 2"),
        (",".join(COLUMNS) + "\n", "holds 0 pair"),
        ("", "no column"),
        (";".join(COLUMNS) + "\n1;2;3;4;5;6\n", "save it as CSV with commas"),
    ],
)
def test_bad_pairs_files_say_what_to_fix(tmp_path: Path, text: str, words: str) -> None:
    path = tmp_path / "pairs.csv"
    path.write_text(text)
    with pytest.raises(InvalidInput, match=words) as info:
        read_pairs(path)
    assert "\n" not in str(info.value)


def test_a_missing_pairs_file_says_what_to_give(tmp_path: Path) -> None:
    with pytest.raises(InvalidInput, match=r"pairs file .* was not found"):
        read_pairs(tmp_path / "nope.csv")
    (tmp_path / "latin1.csv").write_bytes("target_x\n\xe9".encode("latin-1"))
    with pytest.raises(InvalidInput, match=r"not UTF-8 text\. Give a CSV file"):
        read_pairs(tmp_path / "latin1.csv")
