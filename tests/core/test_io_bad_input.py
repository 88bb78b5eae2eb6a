"""Bad input to the readers: missing, empty, truncated, corrupt or lying files.

Each refusal is an InvalidInput that says what is wrong and what to do, and comes at
once (no hang, no huge allocation); valid but odd files still read.
"""

from __future__ import annotations

import dataclasses
import logging
import os
import struct
import sys

import numpy as np
import pytest
from _clouds import ply_header
from _clouds import small_cloud as make_small_cloud

from amrst import io
from amrst.errors import InvalidInput
from amrst.types import Cloud


@pytest.fixture
def small_cloud() -> Cloud:
    return make_small_cloud()


def test_missing_file(tmp_path):
    with pytest.raises(InvalidInput, match="File not found"):
        io.read(tmp_path / "nope.las")


def test_a_file_name_that_is_not_utf8_is_refused_in_words(
    tmp_path, small_cloud, capsys
):
    from amrst.cli import main

    io.write(tmp_path / "ok.ply", small_cloud)
    latin = os.fsdecode(bytes(tmp_path) + b"/\xe9t\xe9.ply")  # Latin-1 "été"
    io.write(latin, dataclasses.replace(small_cloud, xyz=small_cloud.xyz + 1.0))
    with pytest.raises(InvalidInput, match=r"\\xe9t\\xe9.ply: this name is not UTF-8"):
        io.read(latin)
    args = ["register", str(tmp_path / "ok.ply"), latin, "--out", str(tmp_path / "o")]
    assert main([*args, "--report", "--quiet"]) == 2
    err = capsys.readouterr().err.strip()
    assert "rename it (the file or its folder)" in err
    assert "\n" not in err


def test_directory(tmp_path):
    (tmp_path / "d.las").mkdir()
    with pytest.raises(InvalidInput, match="is a folder"):
        io.read(tmp_path / "d.las")


def test_unknown_extension_lists_supported(tmp_path):
    (tmp_path / "scan.rcp").write_bytes(b"x")
    with pytest.raises(InvalidInput, match=r"Supported: \.las, \.laz"):
        io.read(tmp_path / "scan.rcp")
    assert io.get_reader(tmp_path / "scan.rcp") is None


@pytest.mark.parametrize("ext", [".las", ".ply", ".pcd", ".txt"])
def test_empty_file(tmp_path, ext):
    (tmp_path / f"e{ext}").write_bytes(b"")
    with pytest.raises(InvalidInput, match="is empty"):
        io.read(tmp_path / f"e{ext}")


@pytest.mark.parametrize("ext", [".las", ".laz", ".ply", ".pcd"])
def test_truncated_binary_file(tmp_path, small_cloud, ext):
    io.write(tmp_path / f"full{ext}", small_cloud)
    data = (tmp_path / f"full{ext}").read_bytes()
    (tmp_path / f"cut{ext}").write_bytes(data[: len(data) * 2 // 3])
    with pytest.raises(InvalidInput, match=rf"cut\{ext}") as info:
        io.read(tmp_path / f"cut{ext}")
    assert "truncated" in str(info.value)


def test_garbage_las_is_invalid_input(tmp_path):
    (tmp_path / "g.las").write_bytes(b"not a las file at all" * 50)
    with pytest.raises(InvalidInput, match=r"g\.las"):
        io.read(tmp_path / "g.las")


def test_malformedply_header(tmp_path):
    (tmp_path / "m.ply").write_bytes(b"ply\nformat\n")
    with pytest.raises(InvalidInput, match="malformed PLY header"):
        io.read(tmp_path / "m.ply")


def test_non_numeric_text_row_names_the_line(tmp_path):
    (tmp_path / "n.txt").write_text("x y z\n1 2 3\n4 5 6\n7 oops 9\n")
    with pytest.raises(InvalidInput, match=r"line 4: 'oops' is not a number"):
        io.read(tmp_path / "n.txt")


def test_ragged_text_row_names_the_line(tmp_path):
    (tmp_path / "r.csv").write_text("1,2,3\n4,5,6\n7,8\n")
    with pytest.raises(InvalidInput, match=r"line 3: 2 values where 3"):
        io.read(tmp_path / "r.csv")


def test_a_text_file_without_line_breaks_is_refused_at_once(tmp_path):
    (tmp_path / "one_line.xyz").write_text(" ".join(["1.5"] * 300_000) + "\n")
    with pytest.raises(InvalidInput, match=r"300,000 values on a line.*line breaks"):
        io.read(tmp_path / "one_line.xyz")


def test_a_scan_mostly_beyond_1e9_m_is_refused_not_cut(tmp_path):
    xyz = np.random.default_rng(0).uniform(-5, 5, (1000, 3))
    xyz[:970] += 1e9 + 10.0  # a few rows under 1e9 m: no scan to keep of them
    np.savetxt(tmp_path / "far.xyz", xyz, fmt="%.3f")
    with pytest.raises(InvalidInput, match=r"970 of its 1,000 points lie beyond 1e9"):
        io.read(tmp_path / "far.xyz")


def test_nan_rows_are_dropped_and_counted(tmp_path, caplog):
    (tmp_path / "nan.txt").write_text("1 2 3 5\nnan 2 3 6\n4 inf 6 7\n7 8 9 8\n")
    with caplog.at_level(logging.WARNING, logger="amrst.io"):
        cloud = io.read(tmp_path / "nan.txt")
    assert len(cloud) == 2
    assert cloud.attributes["intensity"].tolist() == [5, 8]
    assert cloud.meta["n_dropped_invalid"] == 2
    assert "dropped 2 of 4" in caplog.text


def test_one_point_is_enough(tmp_path):
    (tmp_path / "one.xyz").write_text("1 2 3\n")
    assert len(io.read(tmp_path / "one.xyz")) == 1


def test_zero_valid_points(tmp_path):
    (tmp_path / "z.txt").write_text("nan nan nan\nnan 1 2\n")
    with pytest.raises(InvalidInput, match=r"no valid points.*column order"):
        io.read(tmp_path / "z.txt")
    nan = Cloud(np.array([[0.0, 0.0, 0.0]]), attributes={})
    io.write(tmp_path / "z.ply", nan)
    raw = (tmp_path / "z.ply").read_bytes()  # the one point's x made NaN
    (tmp_path / "z.ply").write_bytes(raw[:-12] + struct.pack("<f", np.nan) + raw[-8:])
    with pytest.raises(InvalidInput, match="no valid points") as info:
        io.read(tmp_path / "z.ply")
    assert "columns=" not in str(info.value)  # a PLY has no columns to give
    (tmp_path / "h.txt").write_text("x y z\n")
    with pytest.raises(InvalidInput, match="no points"):
        io.read(tmp_path / "h.txt")


def test_ply_with_zero_vertices(tmp_path):
    header = ply_header(
        "binary_little_endian",
        0,
        "property float x\nproperty float y\nproperty float z\n",
    )
    (tmp_path / "z.ply").write_bytes(header)
    with pytest.raises(InvalidInput, match="contains no points"):
        io.read(tmp_path / "z.ply")


@pytest.mark.parametrize("ext", [".las", ".ply", ".pcd", ".csv"])
def test_an_empty_cloud_can_be_written(tmp_path, ext):
    empty = Cloud(np.zeros((0, 3)), attributes={"normal": np.zeros((0, 3))})
    io.write(tmp_path / f"e{ext}", empty)
    with pytest.raises(InvalidInput, match="no points"):
        io.read(tmp_path / f"e{ext}")


@pytest.mark.parametrize("backend", ["Lazrs", "LazrsParallel"])
def test_an_empty_laz_is_refused_without_a_warning(tmp_path, backend, caplog):
    import laspy

    las = laspy.LasData(laspy.LasHeader(point_format=3, version="1.2"))
    las.write(tmp_path / "e.laz", laz_backend=getattr(laspy.LazBackend, backend))
    with (
        caplog.at_level(logging.WARNING, logger="amrst"),
        pytest.raises(InvalidInput, match="contains no points"),
    ):
        io.read(tmp_path / "e.laz")
    assert not caplog.records  # the refusal is the only message


# --- lying counts, permissions, misnamed files (LAS/LAZ headers: test_io_bad_las.py)


def _replace_reader(monkeypatch, ext: str, error: Exception) -> None:
    def fail(*args, **kwargs):
        raise error

    fmt = io._FORMATS[ext]
    monkeypatch.setitem(io._FORMATS, ext, dataclasses.replace(fmt, read=fail))


def test_permission_denied_says_so(tmp_path, small_cloud, monkeypatch):
    io.write(tmp_path / "p.ply", small_cloud)
    _replace_reader(
        monkeypatch, ".ply", PermissionError(13, "Permission denied", "p.ply")
    )
    with pytest.raises(InvalidInput, match="permission denied: fix the file's perm"):
        io.read(tmp_path / "p.ply")


@pytest.mark.skipif(
    sys.platform == "win32" or os.geteuid() == 0, reason="root reads any file"
)
def test_unreadable_file(tmp_path, small_cloud):
    io.write(tmp_path / "p.las", small_cloud)
    (tmp_path / "p.las").chmod(0)
    with pytest.raises(InvalidInput, match="permission denied"):
        io.read(tmp_path / "p.las")


@pytest.mark.parametrize("binary", [True, False])
def test_ply_absurd_vertex_count_is_corrupt_not_out_of_memory(
    tmp_path, small_cloud, binary
):
    io.write(tmp_path / "v.ply", small_cloud, binary=binary)
    data = (tmp_path / "v.ply").read_bytes()
    data = data.replace(b"element vertex 200\n", b"element vertex 999999999999\n")
    (tmp_path / "h.ply").write_bytes(data)
    with pytest.raises(InvalidInput, match="truncated") as info:
        io.read(tmp_path / "h.ply")
    assert "memory" not in str(info.value)
    if binary:
        assert (
            "announces 999,999,999,999 points but the file holds only about 200:"
            in (str(info.value))
        )


@pytest.mark.parametrize("data_type", ["binary", "ascii"])
def test_pcd_absurd_point_count_is_corrupt_not_out_of_memory(
    tmp_path, small_cloud, data_type
):
    io.write(tmp_path / "v.pcd", small_cloud, binary=data_type == "binary")
    data = (tmp_path / "v.pcd").read_bytes()
    for key in (b"WIDTH", b"POINTS"):
        data = data.replace(key + b" 200\n", key + b" 99999999999\n")
    (tmp_path / "h.pcd").write_bytes(data)
    with pytest.raises(InvalidInput, match="truncated") as info:
        io.read(tmp_path / "h.pcd")
    assert "memory" not in str(info.value)
    if data_type == "binary":
        assert "announces 99,999,999,999 points but the file holds only about 200:" in (
            str(info.value)
        )


def _lzf_literals(data: bytes) -> bytes:
    """LZF stream of literal runs only (valid, just not compressed)."""
    return b"".join(
        bytes([len(data[i : i + 32]) - 1]) + data[i : i + 32]
        for i in range(0, len(data), 32)
    )


def test_pcd_compressed_sizes_are_checked_before_allocating(tmp_path):
    xyz = np.arange(30, dtype="<f4").reshape(10, 3)
    packed = _lzf_literals(b"".join(xyz[:, i].tobytes() for i in range(3)))
    head = (
        b"VERSION 0.7\nFIELDS x y z\nSIZE 4 4 4\nTYPE F F F\nCOUNT 1 1 1\n"
        b"WIDTH 10\nHEIGHT 1\nPOINTS 10\nDATA binary_compressed\n"
    )
    good = head + struct.pack("<II", len(packed), 120) + packed
    (tmp_path / "ok.pcd").write_bytes(good)
    np.testing.assert_array_equal(io.read(tmp_path / "ok.pcd").xyz, xyz)
    (tmp_path / "size.pcd").write_bytes(
        head + struct.pack("<II", len(packed), 4_000_000_000) + packed
    )
    with pytest.raises(InvalidInput, match="compressed data says 4,000,000,000 b"):
        io.read(tmp_path / "size.pcd")
    (tmp_path / "packed.pcd").write_bytes(
        head + struct.pack("<II", 4_000_000_000, 120) + packed
    )
    with pytest.raises(InvalidInput, match="announces 4,000,000,000 bytes"):
        io.read(tmp_path / "packed.pcd")


def test_negative_counts_are_malformed_headers(tmp_path):
    props = "property float x\nproperty float y\nproperty float z\n"
    (tmp_path / "n.ply").write_bytes(
        ply_header("binary_little_endian", -5, props) + bytes(120)
    )
    with pytest.raises(InvalidInput, match=r"malformed PLY header.*negative count"):
        io.read(tmp_path / "n.ply")
    (tmp_path / "n.pcd").write_bytes(
        b"VERSION 0.7\nFIELDS x y z\nSIZE 4 4 4\nTYPE F F F\nCOUNT 1 1 1\n"
        b"WIDTH 1\nHEIGHT 1\nPOINTS -5\nDATA binary\n" + bytes(120)
    )
    with pytest.raises(InvalidInput, match="negative number of points"):
        io.read(tmp_path / "n.pcd")


def test_ply_body_longer_than_announced_warns(tmp_path, small_cloud, caplog):
    io.write(tmp_path / "v.ply", small_cloud)
    data = (tmp_path / "v.ply").read_bytes()
    (tmp_path / "less.ply").write_bytes(
        data.replace(b"element vertex 200\n", b"element vertex 50\n")
    )
    (tmp_path / "nl.ply").write_bytes(data + b"\n")  # a stray newline is no reason
    with caplog.at_level(logging.WARNING, logger="amrst"):
        assert len(io.read(tmp_path / "nl.ply")) == 200
        assert not caplog.records
        assert len(io.read(tmp_path / "less.ply")) == 50
    assert "announces 50 points but the file holds about 150 more" in caplog.text
    assert all(r.levelno == logging.WARNING for r in caplog.records)


@pytest.mark.parametrize(
    ("name", "content", "kind"),
    [
        ("b.csv", np.random.default_rng(0).bytes(20000), "binary"),
        ("b.xyz", np.arange(3000, dtype="<f8").tobytes(), "binary"),
        ("p.xyz", b"ply\nformat binary_little_endian 1.0\nend_header\n", "PLY"),
        ("p.txt", b"# .PCD v0.7\nVERSION 0.7\nFIELDS x y z\n", "PCD"),
        ("p.pts", b"VERSION 0.7\nFIELDS x y z\n", "PCD"),
        ("l.xyz", b"LASF" + bytes(400), "LAS/LAZ"),
    ],
)
def test_text_reader_refuses_binary_and_other_formats(tmp_path, name, content, kind):
    (tmp_path / name).write_bytes(content)
    with pytest.raises(InvalidInput) as info:
        io.read(tmp_path / name)
    message = str(info.value)
    assert f"not a text point cloud (it looks like a {kind} file)" in message
    assert "give it its real extension" in message
    assert len(message) < len(str(tmp_path)) + 200


def test_text_messages_quote_at_most_80_characters(tmp_path, caplog):
    # Good lines first, so the start of the file still looks like text.
    (tmp_path / "t.xyz").write_bytes(b"1 2 3\n" * 1000 + b"4 5 6 " + b"\x01" * 300)
    with pytest.raises(InvalidInput, match=r"line 1001: 4 values") as info:
        io.read(tmp_path / "t.xyz")
    assert "\\x01" * 20 not in str(info.value)
    assert "..." in str(info.value)
    (tmp_path / "n.xyz").write_text("1 2 3\n" + "4 5 " + "7" * 30 + "x" * 300 + "\n")
    with pytest.raises(InvalidInput, match="not a number") as info:
        io.read(tmp_path / "n.xyz")
    assert "x" * 41 not in str(info.value)
    (tmp_path / "h.xyz").write_text("a" * 500 + " b c\n1 2 3\n")
    with caplog.at_level(logging.WARNING, logger="amrst"):
        io.read(tmp_path / "h.xyz")
    assert "has no x/y/z columns" in caplog.text
    assert "a" * 81 not in caplog.text


def test_text_with_a_latin1_header_is_still_text(tmp_path):
    (tmp_path / "l.csv").write_bytes("x,y,z,höhe\n1,2,3,4\n5,6,7,8\n".encode("latin-1"))
    assert len(io.read(tmp_path / "l.csv")) == 2


def test_absurd_coordinates_are_dropped_like_nan(tmp_path, caplog):
    (tmp_path / "e.xyz").write_text(
        "1 2 3\n1e300 1e300 1e300\n4 5 6\n-2e9 0 0\n6378137 0 0\n"
    )
    with caplog.at_level(logging.WARNING, logger="amrst.io"):
        cloud = io.read(tmp_path / "e.xyz")
    assert len(cloud) == 3  # an ECEF-sized 6378137 m is kept
    assert cloud.meta["n_dropped_invalid"] == 2
    assert "dropped 2 of 5" in caplog.text
    assert np.abs(cloud.world_xyz).max() == 6378137.0
    io.describe(cloud)  # no overflow warning (warnings are errors in tests)
    (tmp_path / "all.xyz").write_text("1e12 1e12 1e12\n2e12 2e12 2e12\n")
    with pytest.raises(InvalidInput, match=r"no valid points.*within 1e9 m"):
        io.read(tmp_path / "all.xyz")


def test_rows_spread_over_more_than_a_local_frame_holds_name_the_file(tmp_path):
    (tmp_path / "wide.xyz").write_text("-9e8 0 0\n9e8 0 0\n0 0 1\n")
    with pytest.raises(InvalidInput, match=r"wide.xyz: its points span 1.8e\+09 m"):
        io.read(tmp_path / "wide.xyz")
