"""Header quirks that leave the points intact, undercounting headers, odd paths.

Quirks are read with one warning that says what was odd; a header
that undercounts its file is reported; a path that is not a regular file is refused
before it is opened, with its own message; decoder noise never reaches the user.
"""

from __future__ import annotations

import logging
import os
import socket
import struct
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from _clouds import GEO_OFFSET, ply_header
from _clouds import small_cloud as make_small_cloud

from amrst import io
from amrst.errors import InvalidInput
from amrst.types import Cloud

ROOT = Path(__file__).resolve().parents[2]


def _written(tmp_path, cloud: Cloud, ext: str) -> bytearray:
    io.write(tmp_path / f"valid{ext}", cloud)
    return bytearray((tmp_path / f"valid{ext}").read_bytes())


# --- LAS header quirks ---------------------------------------------------------------


def test_las_bounds_in_raw_integer_units_read_with_a_warning(tmp_path, caplog):
    rng = np.random.default_rng(4)
    cloud = Cloud(rng.uniform(0, 10, (300, 3)), GEO_OFFSET)
    data = _written(tmp_path, cloud, ".las")
    scales = np.array(struct.unpack_from("<3d", data, 131))
    offsets = np.array(struct.unpack_from("<3d", data, 155))
    bounds = np.array(struct.unpack_from("<6d", data, 179))  # max x, min x, max y ..
    raw = (bounds.reshape(3, 2) - offsets[:, None]) / scales[:, None]
    struct.pack_into("<6d", data, 179, *np.round(raw).ravel())
    (tmp_path / "raw.las").write_bytes(data)
    with caplog.at_level(logging.WARNING):
        got = io.read(tmp_path / "raw.las")
    assert len(got) == 300
    np.testing.assert_allclose(
        got.xyz + got.offset, cloud.xyz + cloud.offset, atol=1e-3
    )
    assert "raw integer units" in caplog.text


def test_las_wrong_bounds_box_with_compact_points_reads_with_a_warning(
    tmp_path, caplog
):
    cloud = Cloud(np.random.default_rng(5).uniform(0, 10, (300, 3)), GEO_OFFSET)
    data = _written(tmp_path, cloud, ".las")
    bounds = np.array(struct.unpack_from("<6d", data, 179))
    struct.pack_into("<6d", data, 179, *(bounds + 5000.0))  # a box 5 km away
    (tmp_path / "off.las").write_bytes(data)
    with caplog.at_level(logging.WARNING):
        assert len(io.read(tmp_path / "off.las")) == 300
    assert "wrong bounds" in caplog.text


def test_las_header_undercounting_its_points_is_reported(tmp_path, caplog):
    data = _written(tmp_path, make_small_cloud(), ".las")
    struct.pack_into("<I", data, 107, 150)  # 200 points in the file
    (tmp_path / "u.las").write_bytes(data)
    with caplog.at_level(logging.WARNING):
        assert len(io.read(tmp_path / "u.las")) == 150
    assert "announces 150 points but the file holds 200" in caplog.text


def test_undercount_warning_reaches_the_command_line(tmp_path):
    """The warning was logged while the decoders' stderr was muted, and lost."""
    data = _written(tmp_path, make_small_cloud(), ".las")
    struct.pack_into("<I", data, 107, 150)
    (tmp_path / "u.las").write_bytes(data)
    proc = subprocess.run(
        [sys.executable, "-m", "amrst.cli", "info", str(tmp_path / "u.las")],
        capture_output=True,
        text=True,
        env={**os.environ, "PYTHONPATH": str(ROOT)},
        timeout=120,
    )
    assert proc.returncode == 0
    assert "announces 150 points but the file holds 200" in proc.stderr


def test_laz_header_undercounting_its_chunks_is_reported(tmp_path, caplog):
    n = 120_000  # two LASzip chunks of 50,000 points and one of 20,000
    cloud = Cloud(np.random.default_rng(6).uniform(0, 10, (n, 3)))
    data = _written(tmp_path, cloud, ".laz")
    struct.pack_into("<I", data, 107, 1000)
    (tmp_path / "u.laz").write_bytes(data)
    with caplog.at_level(logging.WARNING):
        assert len(io.read(tmp_path / "u.laz")) == 1000
    assert "hold at least 100000" in caplog.text


def _laz_announcing(tmp_path: Path, n: int, announced: int, point_format: int) -> Path:
    """Write ``n`` points as LAZ with laspy, then make its header announce fewer."""
    import laspy

    header = laspy.LasHeader(
        point_format=point_format, version="1.4" if point_format >= 6 else "1.2"
    )
    header.scales, header.offsets = [0.001] * 3, [0.0] * 3
    las = laspy.LasData(header)
    las.x, las.y, las.z = np.random.default_rng(7).uniform(0, 10, (n, 3)).T
    path = tmp_path / f"f{point_format}_{n}_{announced}.laz"
    las.write(path, laz_backend=laspy.LazBackend.Lazrs)
    data = bytearray(path.read_bytes())
    if struct.unpack_from("<I", data, 107)[0]:  # the legacy count, 0 for formats 6+
        struct.pack_into("<I", data, 107, announced)
    if data[25] >= 4:
        struct.pack_into("<Q", data, 247, announced)
    path.write_bytes(data)
    return path


@pytest.mark.parametrize("point_format", [3, 6])  # pointwise and layered LASzip
@pytest.mark.parametrize(
    ("n", "announced"),
    [(10_000, 5_000), (120_000, 110_000)],  # one chunk; the last of three
)
def test_laz_header_undercounting_its_last_chunk_is_reported(
    tmp_path, caplog, point_format, n, announced
):
    path = _laz_announcing(tmp_path, n, announced, point_format)
    with caplog.at_level(logging.WARNING):
        assert len(io.read(path)) == announced
    assert f"announces {announced} points but its last compressed chunk" in (
        caplog.text
    )
    assert "holds more points" in caplog.text


@pytest.mark.parametrize("point_format", [3, 6])
def test_laz_header_counting_right_is_read_silently(tmp_path, caplog, point_format):
    path = _laz_announcing(tmp_path, 120_000, 120_000, point_format)
    with caplog.at_level(logging.WARNING):
        assert len(io.read(path)) == 120_000
    assert "announces" not in caplog.text


def test_truncated_laz_gives_one_line_without_laspy_log_lines(tmp_path):
    """A truncated LAZ gives our one line, without laspy's own log lines."""
    cloud = Cloud(np.random.default_rng(7).uniform(0, 10, (5000, 3)))
    data = _written(tmp_path, cloud, ".laz")
    (tmp_path / "cut.laz").write_bytes(data[: len(data) // 2])
    proc = subprocess.run(
        [sys.executable, "-m", "amrst.cli", "info", str(tmp_path / "cut.laz")],
        capture_output=True,
        text=True,
        env={**os.environ, "PYTHONPATH": str(ROOT)},
        timeout=120,
    )
    assert proc.returncode == 2
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1, proc.stderr
    assert "truncated" in lines[0]
    assert "export it again" in lines[0]


# --- undercounting headers of the other formats -------------------------------------


def test_ascii_ply_header_undercounting_is_reported(tmp_path, caplog):
    body = "".join(f"{i} {i} {i}\n" for i in range(10))
    head = ply_header(
        "ascii", 6, "property float x\nproperty float y\nproperty float z\n"
    )
    (tmp_path / "u.ply").write_bytes(head + body.encode())
    with caplog.at_level(logging.WARNING):
        assert len(io.read(tmp_path / "u.ply")) == 6
    assert "announces 6 points but the file holds about 4 more" in caplog.text


@pytest.mark.parametrize("binary", [False, True])
def test_pcd_header_undercounting_is_reported(tmp_path, caplog, binary):
    io.write(tmp_path / "p.pcd", make_small_cloud(), binary=binary)
    data = (tmp_path / "p.pcd").read_bytes()
    data = data.replace(b"WIDTH 200", b"WIDTH 150").replace(
        b"POINTS 200", b"POINTS 150"
    )
    (tmp_path / "u.pcd").write_bytes(data)
    with caplog.at_level(logging.WARNING):
        assert len(io.read(tmp_path / "u.pcd")) == 150
    assert "announces 150 points but the file holds about 50 more" in caplog.text


# --- PCD -------------------------------------------------------------------------------


def test_pcd_upper_case_fields_read(tmp_path):
    head = (
        "VERSION 0.7\nFIELDS X Y Z Intensity\nSIZE 4 4 4 4\nTYPE F F F F\n"
        "COUNT 1 1 1 1\nWIDTH 2\nHEIGHT 1\nPOINTS 2\nDATA ascii\n"
    )
    (tmp_path / "u.pcd").write_text(head + "1 2 3 9\n4 5 6 8\n")
    cloud = io.read(tmp_path / "u.pcd")
    np.testing.assert_allclose(cloud.xyz, [[1, 2, 3], [4, 5, 6]])
    assert cloud.attributes["Intensity"].tolist() == [9, 8]


def _compressed_pcd(n: int, packed: bytes, size: int) -> bytes:
    head = (
        "VERSION 0.7\nFIELDS x y z\nSIZE 4 4 4\nTYPE F F F\nCOUNT 1 1 1\n"
        f"WIDTH {n}\nHEIGHT 1\nPOINTS {n}\nDATA binary_compressed\n"
    )
    return head.encode() + struct.pack("<II", len(packed), size) + packed


@pytest.mark.timeout(20)
def test_pcd_compressed_size_beyond_what_lzf_can_expand_is_refused_at_once(tmp_path):
    n = 30_000_000  # 360 MB announced, 9 MB of data: LZF expands at most 88x
    packed = b"\x00\x00" * 2_000_000
    (tmp_path / "c.pcd").write_bytes(_compressed_pcd(n, packed, n * 12))
    with pytest.raises(InvalidInput, match="cannot hold that much"):
        io.read(tmp_path / "c.pcd")


@pytest.mark.timeout(20)
def test_pcd_compressed_data_running_short_is_refused_fast(tmp_path):
    """A compressed PCD whose data run short is refused as the decoder meets it."""
    n = 750_000  # 9 MB announced, the data are 2-byte literal runs of 1 byte
    packed = b"\x00\x07" * 1_000_000  # decompresses to 1 MB only
    (tmp_path / "s.pcd").write_bytes(_compressed_pcd(n, packed, n * 12))
    with pytest.raises(InvalidInput, match="compressed point data are corrupt"):
        io.read(tmp_path / "s.pcd")


# --- paths that are not regular files ------------------------------------------------


@pytest.mark.timeout(10)
@pytest.mark.parametrize("ext", [".ply", ".las", ".txt", ".xyz"])
def test_fifo_is_refused_without_blocking(tmp_path, ext):
    os.mkfifo(tmp_path / f"f{ext}")
    with pytest.raises(InvalidInput, match="named pipe"):
        io.read(tmp_path / f"f{ext}")


def test_character_device_is_refused(tmp_path):
    (tmp_path / "zero.ply").symlink_to("/dev/zero")
    with pytest.raises(InvalidInput, match="character device"):
        io.read(tmp_path / "zero.ply")


def test_socket_is_refused(tmp_path):
    sock = socket.socket(socket.AF_UNIX)
    path = tmp_path / "s.las"
    try:
        sock.bind(str(path))
        with pytest.raises(InvalidInput, match="socket"):
            io.read(path)
    finally:
        sock.close()


def test_symlink_loop_has_its_own_message(tmp_path):
    (tmp_path / "a.ply").symlink_to(tmp_path / "b.ply")
    (tmp_path / "b.ply").symlink_to(tmp_path / "a.ply")
    with pytest.raises(InvalidInput, match="symbolic link loop"):
        io.read(tmp_path / "a.ply")


def test_broken_link_names_its_target(tmp_path):
    (tmp_path / "l.ply").symlink_to(tmp_path / "gone.ply")
    with pytest.raises(InvalidInput, match="broken link"):
        io.read(tmp_path / "l.ply")


def test_pts_holding_only_its_count_has_no_points(tmp_path):
    (tmp_path / "z.pts").write_text("0\n")
    with pytest.raises(InvalidInput, match="has no points"):
        io.read(tmp_path / "z.pts")


def test_pts_cut_short_of_its_count_is_refused(tmp_path):
    rows = "".join(f"{k} 0 1 50\n" for k in range(3))
    (tmp_path / "cut.pts").write_text("1000\n" + rows)
    with pytest.raises(InvalidInput, match="holds 3 points but its first line says"):
        io.read(tmp_path / "cut.pts")
    (tmp_path / "more.pts").write_text("2\n" + rows)  # a miscount: every point read
    assert len(io.read(tmp_path / "more.pts")) == 3


# --- duplicate points ----------------------------------------------------------------


@pytest.mark.timeout(60)
def test_describe_of_a_tree_plus_a_million_copies_of_one_point_ends():
    rng = np.random.default_rng(8)
    tree = rng.normal(size=(9428, 3))
    cloud = Cloud(np.vstack([tree, np.zeros((1_000_000, 3))]))
    d = io.describe(cloud)
    assert d["median_spacing_m"] == 0.0  # most sampled points have a copy


def test_describe_spacing_unchanged_on_a_cloud_without_copies():
    from scipy.spatial import cKDTree

    xyz = np.random.default_rng(9).uniform(0, 10, (30_000, 3))
    sample = np.random.default_rng(0).choice(len(xyz), size=20_000, replace=False)
    dist, _ = cKDTree(xyz).query(xyz[sample], k=2)
    assert io.describe(Cloud(xyz))["median_spacing_m"] == float(np.median(dist[:, 1]))


def test_truncated_legacy_laz_is_refused_not_crashed(tmp_path):
    """The laszip library crashes on truncated files: it runs in a child process."""
    peer = ROOT / "tests" / "data" / "peer"
    data = (peer / "pdal-simple-laszip-compressor-version-1.2r0.laz").read_bytes()
    for cut in (len(data) * 2 // 3, 400):
        (tmp_path / "cut.laz").write_bytes(data[:cut])
        with pytest.raises(InvalidInput, match="corrupt or truncated"):
            io.read(tmp_path / "cut.laz")


_ACTIONS = ("again", "re-save", "give ", "fix", "check", "choose", "convert", "name ")


@pytest.mark.parametrize(
    ("name", "content"),
    [
        ("a.ply", b"plx\nformat ascii 1.0\n"),
        ("b.ply", b"ply\nformat ascii 1.0\nelement face 0\nend_header\n"),
        ("c.ply", ply_header("ascii", 1, "property float u\n") + b"1\n"),
        ("d.pcd", b"VERSION 0.7\nFIELDS x y z\n"),
        (
            "e.pcd",
            b"FIELDS x y z\nSIZE 4 4\nTYPE F F F\nCOUNT 1 1 1\nPOINTS 1\nDATA ascii\n",
        ),
        (
            "f.pcd",
            b"FIELDS a b c\nSIZE 4 4 4\nTYPE F F F\nPOINTS 1\nDATA ascii\n1 2 3\n",
        ),
    ],
)
def test_every_refusal_says_what_to_do(tmp_path, name, content):
    """Every refusal of a bad file says what to do, not only what is wrong."""
    (tmp_path / name).write_bytes(content)
    with pytest.raises(InvalidInput) as info:
        io.read(tmp_path / name)
    message = str(info.value).lower()
    assert any(action in message for action in _ACTIONS), message


def test_text_refusal_is_one_line_even_after_an_odd_header(tmp_path, caplog):
    (tmp_path / "h.txt").write_text("boundary : a b c\nedge_length : 0.5\n")
    with caplog.at_level(logging.WARNING), pytest.raises(InvalidInput, match="line 2"):
        io.read(tmp_path / "h.txt")
    assert not caplog.records  # the "no x/y/z columns" warning came first before


@pytest.mark.parametrize("damage", ["garbage", "zeros", "cut"])
def test_damaged_laz_chunk_table_is_one_refusal_without_a_crash(tmp_path, damage):
    """lazrs panicked on a garbage table (exit 1); laspy then tried laszip in-process,
    which can crash the interpreter on truncated data: only lazrs runs in-process."""
    cloud = Cloud(np.random.default_rng(1).uniform(0, 10, (5000, 3)))
    data = _written(tmp_path, cloud, ".laz")
    (start,) = struct.unpack_from("<I", data, 96)
    (table,) = struct.unpack_from("<q", data, start)
    body = len(data) - table - 8
    if damage == "garbage":
        data[table + 8 :] = b"\xff" * body
    elif damage == "zeros":
        data[table + 8 :] = b"\x00" * body
    else:
        del data[table + 9 :]
    (tmp_path / "d.laz").write_bytes(data)
    proc = subprocess.run(
        [sys.executable, "-m", "amrst.cli", "info", str(tmp_path / "d.laz")],
        capture_output=True,
        text=True,
        env={**os.environ, "PYTHONPATH": str(ROOT)},
        timeout=120,
    )
    assert proc.returncode == 2, proc.stderr
    assert len(proc.stderr.strip().splitlines()) == 1
    assert "Laszip" not in proc.stderr  # lazrs's message, not the in-process fallback


def test_register_with_a_symlink_loop_is_one_line(tmp_path, capsys):
    """Hostile corpus: 'register LOOP LOOP' was "Internal error: RuntimeError"."""
    from amrst import cli

    (tmp_path / "a.ply").symlink_to(tmp_path / "b.ply")
    (tmp_path / "b.ply").symlink_to(tmp_path / "a.ply")
    loop = str(tmp_path / "a.ply")
    code = cli.main(["register", loop, loop, "--out", str(tmp_path / "out")])
    assert code == cli.EXIT_INPUT
    assert "symbolic link loop" in capsys.readouterr().err
