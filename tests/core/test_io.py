"""amrst.io: round trips in every format, georeferencing, bad input, atomic writes."""

from __future__ import annotations

import dataclasses
import logging
import os
import struct
import sys

import numpy as np
import pytest

from amrst import io
from amrst.errors import AmrstError, InvalidInput
from amrst.types import Cloud, make_transform, transform_cloud

GEO_OFFSET = np.array([500000.0, 5000000.0, 250.0])
FORMATS = [
    (".las", True),
    (".laz", True),
    (".ply", True),
    (".ply", False),
    (".pcd", True),
    (".pcd", False),
    (".xyz", True),
    (".txt", True),
    (".csv", True),
]


def _attributes(n: int, rng: np.random.Generator) -> dict[str, np.ndarray]:
    return {
        "intensity": rng.integers(0, 65535, n).astype(np.uint16),
        "red": rng.integers(0, 256, n).astype(np.uint8),
        "green": rng.integers(0, 256, n).astype(np.uint8),
        "blue": rng.integers(0, 256, n).astype(np.uint8),
        "return_number": rng.integers(1, 4, n).astype(np.uint8),
        "number_of_returns": np.full(n, 3, np.uint8),
        "classification": rng.integers(0, 20, n).astype(np.uint8),
        "gps_time": rng.uniform(0, 1e5, n),
        "scan_id": np.ones(n, np.uint8),
        "wood": rng.integers(0, 2, n).astype(np.uint8),
        "reflectance": rng.normal(size=n).astype(np.float32),
    }


@pytest.fixture
def geo_cloud() -> Cloud:
    """300 points of a 'tree' at x~500000, y~5000000 with millimetre decimals."""
    rng = np.random.default_rng(7)
    xyz = np.round(rng.uniform(0, 20, (300, 3)), 3) + np.array([0.123, 0.456, 0.789])
    return Cloud(xyz, GEO_OFFSET, _attributes(300, rng), "geo")


@pytest.fixture
def small_cloud() -> Cloud:
    rng = np.random.default_rng(3)
    return Cloud(
        rng.uniform(-5, 5, (200, 3)), attributes={"wood": np.ones(200, np.uint8)}
    )


def _assert_same_attributes(expected: Cloud, actual: Cloud) -> None:
    assert set(expected.attributes) <= set(actual.attributes)
    for name, values in expected.attributes.items():
        got = np.asarray(actual.attributes[name], dtype=np.float64)
        np.testing.assert_array_equal(got, np.asarray(values, np.float64), err_msg=name)


# --- round trips ---------------------------------------------------------------


@pytest.mark.parametrize(("ext", "binary"), FORMATS)
def test_round_trip_keeps_attributes_and_millimetres(tmp_path, geo_cloud, ext, binary):
    first = tmp_path / f"first{ext}"
    io.write(first, geo_cloud, binary=binary)
    cloud = io.read(first)
    np.testing.assert_allclose(cloud.world_xyz, geo_cloud.world_xyz, rtol=0, atol=1e-4)
    _assert_same_attributes(geo_cloud, cloud)
    assert np.abs(cloud.xyz).max() < 1e4, "large values belong in the offset"

    # read -> transform -> write -> read in the same format keeps everything
    angle = np.radians(30.0)
    R = np.array(
        [
            [np.cos(angle), -np.sin(angle), 0],
            [np.sin(angle), np.cos(angle), 0],
            [0, 0, 1],
        ]
    )
    T_target_source = make_transform(R, [12.3456, -7.891, 0.5])
    moved = transform_cloud(T_target_source, cloud)
    second = tmp_path / f"second{ext}"
    io.write(second, moved, binary=binary)
    again = io.read(second)
    np.testing.assert_allclose(again.world_xyz, moved.world_xyz, rtol=0, atol=1e-4)
    _assert_same_attributes(cloud, again)
    assert again.meta["n_dropped_invalid"] == 0


def test_small_local_cloud_uses_float32_in_ply_and_pcd(tmp_path, small_cloud):
    for ext in (".ply", ".pcd"):
        io.write(tmp_path / f"c{ext}", small_cloud)
        cloud = io.read(tmp_path / f"c{ext}")
        assert cloud.meta["coord_dtype"] == "float32"
        np.testing.assert_allclose(cloud.xyz, small_cloud.xyz, atol=1e-5)
        np.testing.assert_array_equal(cloud.offset, 0.0)
    head = (tmp_path / "c.ply").read_bytes()[:200]
    assert b"property float x" in head


def test_georeferenced_cloud_uses_doubles_in_ply(tmp_path, geo_cloud):
    io.write(tmp_path / "g.ply", geo_cloud)
    assert b"property double x" in (tmp_path / "g.ply").read_bytes()[:400]


def test_las_reads_header_offset_and_extra_dims(tmp_path):
    laspy = pytest.importorskip("laspy")
    header = laspy.LasHeader(point_format=3)
    header.offsets = [500000.0, 5000000.0, 0.0]
    header.scales = [0.001, 0.001, 0.001]
    header.add_extra_dims([laspy.ExtraBytesParams("tree_id", "u2")])
    las = laspy.LasData(header)
    las.x = np.array([500000.123, 500001.456, 500002.789])
    las.y = np.array([5000000.001, 5000000.002, 5000000.003])
    las.z = np.array([1.0, 2.0, 3.0])
    las.intensity = np.array([10, 20, 30])
    las.tree_id = np.array([7, 7, 8])
    las.write(tmp_path / "h.las")

    cloud = io.read(tmp_path / "h.las")
    np.testing.assert_array_equal(cloud.offset, [500000.0, 5000000.0, 0.0])
    np.testing.assert_allclose(cloud.xyz[:, 0], [0.123, 1.456, 2.789], atol=1e-9)
    assert cloud.attributes["tree_id"].tolist() == [7, 7, 8]
    assert cloud.meta["las_point_format"] == 3
    assert cloud.meta["las_scales"] == (0.001, 0.001, 0.001)


def test_las_unknown_attributes_become_extra_dims(tmp_path, geo_cloud):
    laspy = pytest.importorskip("laspy")
    io.write(tmp_path / "x.las", geo_cloud)
    las = laspy.read(tmp_path / "x.las")
    extra = set(las.point_format.extra_dimension_names)
    assert {"scan_id", "wood", "reflectance"} <= extra
    assert las.point_format.id == 3  # gps_time and RGB: point format 3
    assert np.asarray(las["wood"]).dtype == np.uint8


def test_las_keeps_values_a_standard_field_cannot_hold(tmp_path):
    intensity = np.array([0.25, 0.5, 70000.0], dtype=np.float32)
    cloud = Cloud(np.eye(3), attributes={"intensity": intensity})
    io.write(tmp_path / "f.laz", cloud)
    again = io.read(tmp_path / "f.laz")
    np.testing.assert_array_equal(again.attributes["intensity"], intensity)


def test_las_vlrs_are_kept(tmp_path, small_cloud):
    laspy = pytest.importorskip("laspy")
    cloud = Cloud(small_cloud.xyz, meta={"las_vlrs": (("amrst", 42, "test", b"crs"),)})
    io.write(tmp_path / "v.las", cloud)
    vlrs = laspy.read(tmp_path / "v.las").vlrs
    assert any(v.user_id == "amrst" and v.record_id == 42 for v in vlrs)


# --- PLY -------------------------------------------------------------------------


def _ply_header(fmt: str, n: int, props: str, extra: str = "") -> bytes:
    return (
        f"ply\nformat {fmt} 1.0\ncomment hand made\nelement vertex {n}\n{props}"
        f"{extra}end_header\n"
    ).encode()


@pytest.mark.parametrize("endian", ["<", ">"])
def test_ply_binary_both_endians_keep_every_property(tmp_path, endian):
    fmt = "binary_little_endian" if endian == "<" else "binary_big_endian"
    dtype = np.dtype(
        [("x", endian + "f8"), ("y", endian + "f8"), ("z", endian + "f8"),
         ("label", "u1"), ("curvature", endian + "f4"), ("count", endian + "i4")]
    )  # fmt: skip
    rec = np.zeros(4, dtype)
    rec["x"] = [500000.001, 500000.002, 500000.003, 500000.004]
    rec["y"], rec["z"] = 5000000.5, [1, 2, 3, 4]
    rec["label"], rec["curvature"], rec["count"] = [1, 2, 3, 4], 0.5, [-1, 0, 1, 2]
    props = (
        "property double x\nproperty double y\nproperty double z\n"
        "property uchar label\nproperty float curvature\nproperty int count\n"
    )
    path = tmp_path / "b.ply"
    path.write_bytes(_ply_header(fmt, 4, props) + rec.tobytes())
    cloud = io.read(path)
    np.testing.assert_allclose(cloud.world_xyz[:, 0], rec["x"], rtol=0, atol=1e-9)
    assert cloud.offset[0] == 500000.0
    assert cloud.attributes["label"].tolist() == [1, 2, 3, 4]
    assert cloud.attributes["count"].tolist() == [-1, 0, 1, 2]
    assert cloud.attributes["curvature"].dtype == np.float32
    assert cloud.meta["ply_format"] == fmt


def test_ply_ascii_with_faces_after_vertices(tmp_path):
    text = (
        _ply_header(
            "ascii",
            3,
            "property float x\nproperty float y\nproperty float z\n"
            "property uchar red\n",
            "element face 1\nproperty list uchar int vertex_indices\n",
        )
        + b"0 0 0 255\n1 0 0 128\n0 1 0 0\n3 0 1 2\n"
    )
    (tmp_path / "a.ply").write_bytes(text)
    cloud = io.read(tmp_path / "a.ply")
    assert len(cloud) == 3
    assert cloud.attributes["red"].dtype == np.uint8
    assert cloud.attributes["red"].tolist() == [255, 128, 0]


def test_ply_large_float32_coordinates_are_rebased(tmp_path):
    rec = np.zeros(2, [("x", "<f4"), ("y", "<f4"), ("z", "<f4")])
    rec["x"] = [500000.0, 500010.0]
    props = "property float x\nproperty float y\nproperty float z\n"
    (tmp_path / "f.ply").write_bytes(
        _ply_header("binary_little_endian", 2, props) + rec.tobytes()
    )
    cloud = io.read(tmp_path / "f.ply")
    np.testing.assert_array_equal(cloud.offset, [500000.0, 0, 0])
    np.testing.assert_array_equal(cloud.xyz[:, 0], [0.0, 10.0])


# --- PCD -------------------------------------------------------------------------


def test_pcd_ascii_unpacks_rgb_and_keeps_multi_count_fields(tmp_path):
    packed = np.array([(255 << 16) | (128 << 8) | 7], np.uint32).view(np.float32)[0]
    text = (
        "VERSION 0.7\nFIELDS x y z rgb hist\nSIZE 4 4 4 4 4\nTYPE F F F F F\n"
        "COUNT 1 1 1 1 2\nWIDTH 2\nHEIGHT 1\nVIEWPOINT 0 0 0 1 0 0 0\nPOINTS 2\n"
        f"DATA ascii\n1 2 3 {float(packed)!r} 0.5 1.5\n"
        f"4 5 6 {float(packed)!r} 2.5 3.5\n"
    )
    (tmp_path / "a.pcd").write_text(text)
    cloud = io.read(tmp_path / "a.pcd")
    assert cloud.attributes["red"].tolist() == [255, 255]
    assert cloud.attributes["green"].tolist() == [128, 128]
    assert cloud.attributes["blue"].tolist() == [7, 7]
    assert cloud.attributes["hist"].shape == (2, 2)
    io.write(tmp_path / "b.pcd", cloud, binary=False)
    _assert_same_attributes(cloud, io.read(tmp_path / "b.pcd"))


def test_pcd_binary_compressed_is_read(tmp_path):
    o3d = pytest.importorskip("open3d")
    rng = np.random.default_rng(0)
    points = rng.uniform(0, 5, (500, 3))
    wood = (np.arange(500) % 3 == 0).astype(np.uint8).reshape(-1, 1)
    pcd = o3d.t.geometry.PointCloud()
    pcd.point.positions = o3d.core.Tensor(points)
    pcd.point.wood = o3d.core.Tensor(wood)
    path = tmp_path / "c.pcd"
    assert o3d.t.io.write_point_cloud(
        str(path), pcd, write_ascii=False, compressed=True
    )
    assert b"binary_compressed" in path.read_bytes()[:300]
    cloud = io.read(path)
    np.testing.assert_array_equal(cloud.xyz, points)
    np.testing.assert_array_equal(cloud.attributes["wood"], wood[:, 0])


# --- text ------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("body", "expected_names"),
    [
        ("1 2 3\n4 5 6\n", []),
        ("x y z\n1 2 3\n4 5 6\n", []),
        ("1,2,3,9\n4,5,6,8\n", ["intensity"]),
        ("X\tY\tZ\tI\n1\t2\t3\t9\n4\t5\t6\t8\n", ["intensity"]),
        ('"x" "y" "z"\n1 2 3\n4 5 6\n', []),
        ("//X,Y,Z,R,G,B\n1,2,3,10,20,30\n4,5,6,40,50,60\n", ["red", "green", "blue"]),
        ("x;y;z\n1,0;2,0;3,0\n4,0;5,0;6,0\n", []),
        ("2\n1 2 3 9 1 1\n4 5 6 8 2 2\n", ["intensity", "col4", "col5"]),
        ("# a comment\n\n1 2 3\n\n4 5 6  # trailing\n", []),
    ],
)
def test_text_layouts(tmp_path, body, expected_names):
    path = tmp_path / "t.txt"
    path.write_text(body)
    cloud = io.read(path)
    np.testing.assert_array_equal(cloud.xyz, [[1, 2, 3], [4, 5, 6]])
    assert list(cloud.attributes) == expected_names


def test_text_header_names_columns_in_any_order(tmp_path):
    (tmp_path / "o.csv").write_text("Intensity,Z,Y,X\n9,3,2,1\n8,6,5,4\n")
    cloud = io.read(tmp_path / "o.csv")
    np.testing.assert_array_equal(cloud.xyz, [[1, 2, 3], [4, 5, 6]])
    assert cloud.attributes["intensity"].tolist() == [9, 8]


def test_text_columns_argument_names_columns(tmp_path):
    (tmp_path / "c.xyz").write_text("1 2 3 100 10 20 30\n4 5 6 200 40 50 60\n")
    names = ["x", "y", "z", "intensity", "red", "green", "blue"]
    cloud = io.read(tmp_path / "c.xyz", columns=names)
    assert cloud.attributes["blue"].tolist() == [30, 60]
    assert cloud.attributes["red"].dtype == np.uint8
    with pytest.raises(InvalidInput, match="must include 'x'"):
        io.read(tmp_path / "c.xyz", columns=["a", "b", "c"])


def test_text_utf16_with_bom(tmp_path):
    (tmp_path / "w.txt").write_bytes("x\ty\tz\n1\t2\t3\n".encode("utf-16"))
    np.testing.assert_array_equal(io.read(tmp_path / "w.txt").xyz, [[1, 2, 3]])


def test_multi_column_attributes_round_trip(tmp_path):
    normals = np.random.default_rng(1).normal(size=(6, 3))
    cloud = Cloud(np.arange(18.0).reshape(6, 3), attributes={"normal": normals})
    io.write(tmp_path / "n.pcd", cloud)
    np.testing.assert_array_equal(
        io.read(tmp_path / "n.pcd").attributes["normal"], normals
    )
    io.write(tmp_path / "n.ply", cloud)  # PLY has no arrays: normal_0, normal_1, ...
    np.testing.assert_array_equal(
        io.read(tmp_path / "n.ply").attributes["normal_2"], normals[:, 2]
    )


def test_text_reads_large_georeferenced_values(tmp_path):
    (tmp_path / "g.txt").write_text(
        "500000.123 5000000.456 12.5\n500001.5 5000001.25 13\n"
    )
    cloud = io.read(tmp_path / "g.txt")
    np.testing.assert_array_equal(cloud.offset, [500000.0, 5000000.0, 0.0])
    np.testing.assert_allclose(cloud.xyz[0], [0.123, 0.456, 12.5], atol=1e-9)


# --- bad input -------------------------------------------------------------------


def test_missing_file(tmp_path):
    with pytest.raises(InvalidInput, match="File not found"):
        io.read(tmp_path / "nope.las")


def test_directory(tmp_path):
    (tmp_path / "d.las").mkdir()
    with pytest.raises(InvalidInput, match="is a folder"):
        io.read(tmp_path / "d.las")


def test_unknown_extension_lists_supported(tmp_path):
    (tmp_path / "scan.e57").write_bytes(b"x")
    with pytest.raises(InvalidInput, match=r"Supported: \.las, \.laz"):
        io.read(tmp_path / "scan.e57")
    assert io.get_reader(tmp_path / "scan.e57") is None


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


def test_malformed_ply_header(tmp_path):
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


def test_nan_rows_are_dropped_and_counted(tmp_path, caplog):
    (tmp_path / "nan.txt").write_text("1 2 3 5\nnan 2 3 6\n4 inf 6 7\n7 8 9 8\n")
    with caplog.at_level(logging.WARNING, logger="amrst.io"):
        cloud = io.read(tmp_path / "nan.txt")
    assert len(cloud) == 2
    assert cloud.attributes["intensity"].tolist() == [5, 8]
    assert cloud.meta["n_dropped_invalid"] == 2
    assert "dropped 2 of 4" in caplog.text
    assert len(io.read(tmp_path / "nan.txt", drop_invalid=False)) == 4


def test_one_point_is_enough(tmp_path):
    (tmp_path / "one.xyz").write_text("1 2 3\n")
    assert len(io.read(tmp_path / "one.xyz")) == 1


def test_zero_valid_points(tmp_path):
    (tmp_path / "z.txt").write_text("nan nan nan\nnan 1 2\n")
    with pytest.raises(InvalidInput, match="no valid points"):
        io.read(tmp_path / "z.txt")
    (tmp_path / "h.txt").write_text("x y z\n")
    with pytest.raises(InvalidInput, match="no points"):
        io.read(tmp_path / "h.txt")


def test_ply_with_zero_vertices(tmp_path):
    header = _ply_header(
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


# --- corrupt headers, lying counts, misnamed files ------------------------------


def _valid_las(tmp_path, cloud: Cloud, ext: str = ".las") -> bytearray:
    io.write(tmp_path / f"valid{ext}", cloud)
    return bytearray((tmp_path / f"valid{ext}").read_bytes())


@pytest.mark.timeout(30)  # laspy used to loop for minutes on these
@pytest.mark.parametrize("ext", [".las", ".laz"])
@pytest.mark.parametrize("n_vlrs", [0xFFFFFFFF, 1000])
def test_las_vlr_count_that_cannot_fit_is_refused_at_once(
    tmp_path, small_cloud, ext, n_vlrs
):
    data = _valid_las(tmp_path, small_cloud, ext)
    struct.pack_into("<I", data, 100, n_vlrs)
    (tmp_path / f"v{ext}").write_bytes(data)
    with pytest.raises(InvalidInput, match=f"announces {n_vlrs:,} variable-length"):
        io.read(tmp_path / f"v{ext}")


@pytest.mark.timeout(30)
@pytest.mark.parametrize("ext", [".las", ".laz"])
def test_las_signature_then_random_bytes_is_refused_at_once(tmp_path, ext):
    rng = np.random.default_rng(0)
    for i in range(20):
        path = tmp_path / f"r{i}{ext}"
        path.write_bytes(b"LASF" + rng.bytes(5000))
        with pytest.raises(InvalidInput, match="corrupt LAS header"):
            io.read(path)


def test_las_too_short_or_not_las(tmp_path):
    (tmp_path / "s.las").write_bytes(b"LASF" + bytes(100))
    with pytest.raises(InvalidInput, match="too short to be a LAS/LAZ file"):
        io.read(tmp_path / "s.las")
    (tmp_path / "p.las").write_bytes(b"ply\nformat ascii 1.0\n" + bytes(300))
    with pytest.raises(InvalidInput, match="is not a LAS/LAZ file"):
        io.read(tmp_path / "p.las")


@pytest.mark.parametrize("ext", [".las", ".laz"])
@pytest.mark.parametrize(
    ("pos", "value", "message"),
    [
        (131, 0.0, "scale factor is 0 for x, so every x coordinate would be 0"),
        (139, -0.001, "scale factor is -0.001 for y"),
        (147, float("nan"), "scale factor is nan for z"),
        (163, float("inf"), "offset is inf for y"),
    ],
)
def test_las_bad_scale_or_offset_is_refused(
    tmp_path, small_cloud, ext, pos, value, message
):
    data = _valid_las(tmp_path, small_cloud, ext)
    struct.pack_into("<d", data, pos, value)
    (tmp_path / f"s{ext}").write_bytes(data)
    with pytest.raises(InvalidInput, match=message):
        io.read(tmp_path / f"s{ext}")


def test_las_header_or_point_data_beyond_the_file(tmp_path, small_cloud):
    data = _valid_las(tmp_path, small_cloud)
    bad = bytearray(data)
    struct.pack_into("<H", bad, 94, 60000)
    (tmp_path / "h.las").write_bytes(bad)
    with pytest.raises(InvalidInput, match="header size of 60000 bytes"):
        io.read(tmp_path / "h.las")
    bad = bytearray(data)
    struct.pack_into("<I", bad, 96, len(data) + 10)
    (tmp_path / "o.las").write_bytes(bad)
    with pytest.raises(InvalidInput, match="after the end of the file"):
        io.read(tmp_path / "o.las")


@pytest.mark.timeout(30)
@pytest.mark.parametrize("ext", [".las", ".laz"])
def test_las14_evlr_count_that_cannot_fit_is_refused_at_once(tmp_path, ext):
    cloud = Cloud(np.eye(3), meta={"las_version": "1.4", "las_point_format": 6})
    data = _valid_las(tmp_path, cloud, ext)
    assert data[24:26] == b"\x01\x04"
    (point_start,) = struct.unpack_from("<I", data, 96)
    struct.pack_into("<QI", data, 235, point_start, 0xFFFFFFFF)
    (tmp_path / f"e{ext}").write_bytes(data)
    with pytest.raises(InvalidInput, match="4,294,967,295 extended variable-length"):
        io.read(tmp_path / f"e{ext}")


@pytest.mark.timeout(30)
@pytest.mark.parametrize(
    ("version", "pos", "fmt"), [("1.2", 107, "<I"), ("1.4", 247, "<Q")]
)
def test_laz_point_count_beyond_its_chunks_is_refused(
    tmp_path, small_cloud, version, pos, fmt
):
    cloud = Cloud(small_cloud.xyz, meta={"las_version": version})
    data = _valid_las(tmp_path, cloud, ".laz")
    struct.pack_into(fmt, data, pos, 1_000_000)  # the point count
    (tmp_path / "c.laz").write_bytes(data)
    with pytest.raises(InvalidInput, match="1,000,000 points but the file's 1 comp"):
        io.read(tmp_path / "c.laz")


def test_las_garbage_point_records_disagree_with_header_bounds(tmp_path, small_cloud):
    data = _valid_las(tmp_path, small_cloud)
    (start,) = struct.unpack_from("<I", data, 96)
    data[start:] = np.random.default_rng(1).bytes(len(data) - start)
    (tmp_path / "g.las").write_bytes(data)
    with pytest.raises(InvalidInput, match="disagree with the header bounds"):
        io.read(tmp_path / "g.las")


def test_las_bounds_check_tolerates_zero_bounds_and_a_few_strays(tmp_path):
    rng = np.random.default_rng(2)
    xyz = rng.uniform(0, 10, (100, 3))
    xyz[:3] += 1000.0  # 3 % of the points far from the rest
    valid = bytes(_valid_las(tmp_path, Cloud(xyz, GEO_OFFSET)))
    zero = bytearray(valid)
    struct.pack_into("<6d", zero, 179, *([0.0] * 6))  # a writer that skips bounds
    (tmp_path / "z.las").write_bytes(zero)
    assert len(io.read(tmp_path / "z.las")) == 100
    tight = bytearray(valid)
    (min_x,) = struct.unpack_from("<d", valid, 187)
    struct.pack_into("<d", tight, 179, min_x + 10.0)  # max x leaves out the strays
    (tmp_path / "t.las").write_bytes(tight)
    assert len(io.read(tmp_path / "t.las")) == 100


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
        _ply_header("binary_little_endian", -5, props) + bytes(120)
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
    assert len(io.read(tmp_path / "e.xyz", drop_invalid=False)) == 5
    (tmp_path / "all.xyz").write_text("1e12 1e12 1e12\n2e12 2e12 2e12\n")
    with pytest.raises(InvalidInput, match=r"no valid points.*within 1e9 m"):
        io.read(tmp_path / "all.xyz")


# --- registry and writing --------------------------------------------------------


def test_get_reader_and_extensions(tmp_path, small_cloud):
    assert io.get_reader("scan.LAZ") is io.read
    assert set(io.supported_extensions()) >= {".las", ".laz", ".ply", ".pcd", ".xyz"}
    io.write(tmp_path / "s.las", small_cloud)
    reader = io.get_reader(tmp_path / "s.las")
    assert reader is not None
    assert len(reader(tmp_path / "s.las")) == len(small_cloud)


def test_write_errors(tmp_path, small_cloud):
    with pytest.raises(InvalidInput, match="does not exist"):
        io.write(tmp_path / "missing" / "a.ply", small_cloud)
    with pytest.raises(InvalidInput, match="unsupported extension"):
        io.write(tmp_path / "a.e57", small_cloud)
    (tmp_path / "dir.ply").mkdir()
    with pytest.raises(InvalidInput, match="is a folder"):
        io.write(tmp_path / "dir.ply", small_cloud)


def test_failed_write_leaves_old_file_and_no_temp(tmp_path, small_cloud, monkeypatch):
    target = tmp_path / "scan.ply"
    target.write_bytes(b"old content")

    def broken_writer(path, cloud, *, binary=True):
        path.write_bytes(b"half a file")
        raise OSError(28, "No space left on device")

    monkeypatch.setitem(io._WRITERS, ".ply", broken_writer)
    with pytest.raises(AmrstError, match="No space left"):
        io.write(target, small_cloud)
    assert target.read_bytes() == b"old content"
    assert [p.name for p in tmp_path.iterdir()] == ["scan.ply"]


def test_write_replaces_existing_file(tmp_path, small_cloud):
    target = tmp_path / "scan.pcd"
    target.write_bytes(b"old content")
    io.write(target, small_cloud)
    assert len(io.read(target)) == len(small_cloud)
    assert [p.name for p in tmp_path.iterdir()] == ["scan.pcd"]


# --- describe --------------------------------------------------------------------


def test_describe_small_cloud():
    grid = np.stack(np.meshgrid(*[np.arange(10) * 0.1] * 3, indexing="ij"), -1)
    xyz = grid.reshape(-1, 3)
    cloud = Cloud(
        xyz,
        GEO_OFFSET,
        {"intensity": np.arange(len(xyz), dtype=np.uint16)},
        "grid",
        {"format": "las", "las_point_format": 3, "las_vlrs": (("a", 1, "d", b""),)},
    )
    d = io.describe(cloud)
    assert d["n_points"] == 1000
    np.testing.assert_allclose(d["bounds_min"], GEO_OFFSET)
    np.testing.assert_allclose(d["extent"], [0.9, 0.9, 0.9])
    assert d["median_spacing_m"] == pytest.approx(0.1)
    assert d["attributes"]["intensity"] == {
        "dtype": "uint16",
        "shape": [],
        "min": 0,
        "max": 999,
    }
    assert d["format"]["las_point_format"] == 3
    text = io.format_description(d)
    assert "1,000" in text
    assert "intensity" in text
    assert "500000.000" in text
