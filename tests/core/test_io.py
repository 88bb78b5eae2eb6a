"""amrst.io: round trips in every format, georeferencing, bad input, atomic writes."""

from __future__ import annotations

import numpy as np
import pytest
from _clouds import GEO_OFFSET, ply_header
from _clouds import small_cloud as make_small_cloud

from amrst import io
from amrst.errors import AmrstError, InvalidInput
from amrst.types import Cloud, make_transform, transform_cloud

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
    return make_small_cloud()


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


def test_las_writes_as_many_extra_attributes_as_it_holds_and_says_so(tmp_path, caplog):
    from amrst.io.las_write import MAX_EXTRA_DIMS

    many = {f"a{k:03d}": np.full(3, float(k), np.float32) for k in range(400)}
    io.write(tmp_path / "f.las", Cloud(np.eye(3), attributes=many))
    assert f"{400 - MAX_EXTRA_DIMS} not written" in caplog.text
    again = io.read(tmp_path / "f.las").attributes
    assert len(again) == MAX_EXTRA_DIMS
    np.testing.assert_array_equal(again["a007"], many["a007"])


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
    path.write_bytes(ply_header(fmt, 4, props) + rec.tobytes())
    cloud = io.read(path)
    np.testing.assert_allclose(cloud.world_xyz[:, 0], rec["x"], rtol=0, atol=1e-9)
    assert cloud.offset[0] == 500000.0
    assert cloud.attributes["label"].tolist() == [1, 2, 3, 4]
    assert cloud.attributes["count"].tolist() == [-1, 0, 1, 2]
    assert cloud.attributes["curvature"].dtype == np.float32
    assert cloud.meta["ply_format"] == fmt


def test_ply_ascii_with_faces_after_vertices(tmp_path):
    text = (
        ply_header(
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
        ply_header("binary_little_endian", 2, props) + rec.tobytes()
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
        ("x y z\r\n1 2 3\r\n4 5 6\r\n", []),  # Windows line ends
        ("# old Mac line ends\r1 2 3\r4 5 6\r", []),
    ],
)
def test_text_layouts(tmp_path, body, expected_names):
    path = tmp_path / "t.txt"
    path.write_bytes(body.encode())
    cloud = io.read(path)
    np.testing.assert_array_equal(cloud.xyz, [[1, 2, 3], [4, 5, 6]])
    assert list(cloud.attributes) == expected_names


def test_text_layout_found_after_a_long_comment_block(tmp_path):
    # Over a megabyte of comments (a scanner's export log) before the points.
    comments = "".join(f"# setting {i}: {'x' * 60}\n" for i in range(20_000))
    for encoding in ("utf-8", "utf-16"):
        path = tmp_path / f"long_{encoding}.txt"
        path.write_bytes(("x y z\n" + comments + "1 2 3\n4 5 6\n").encode(encoding))
        np.testing.assert_array_equal(io.read(path).xyz, [[1, 2, 3], [4, 5, 6]])


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


def test_a_large_text_file_is_read_holding_its_numbers_not_its_text(tmp_path):
    import tracemalloc

    rng = np.random.default_rng(3)
    xyz = rng.uniform(-20, 20, size=(50_000, 3))
    rows = [f"{x:.4f};{y:.4f};{z:.4f};{i}" for i, (x, y, z) in enumerate(xyz)]
    body = "\n".join(row.replace(".", ",") for row in rows)  # decimal commas
    path = tmp_path / "big.csv"
    path.write_text(f"X;Y;Z;Intensity\n{body}\n")
    assert path.stat().st_size > 1_000_000  # its layout is read from the start only
    tracemalloc.start()
    cloud = io.read(path)
    _, top = tracemalloc.get_traced_memory()
    tracemalloc.stop()
    np.testing.assert_allclose(cloud.xyz + cloud.offset, xyz, atol=1e-4)
    assert cloud.attributes["intensity"][-1] == 49_999
    # The numbers and a few copies of them; the file's text whole costs more.
    assert top < 8 * cloud.xyz.nbytes
    lines = path.read_text().splitlines()
    lines[40_000] = "1,5;2,5"
    path.write_text("\n".join(lines))
    with pytest.raises(InvalidInput, match=r"line 40001: 2 values where 4"):
        io.read(path)


@pytest.mark.parametrize("ext", ["ply", "pcd"])
def test_an_ascii_ply_or_pcd_is_read_holding_its_numbers_not_its_text(tmp_path, ext):
    import tracemalloc

    from amrst.io.pcd import write_pcd
    from amrst.io.ply import write_ply

    xyz = np.random.default_rng(4).uniform(-20, 20, size=(50_000, 3))
    write = write_ply if ext == "ply" else write_pcd
    write(tmp_path / f"a.{ext}", Cloud(xyz), binary=False)
    tracemalloc.start()
    cloud = io.read(tmp_path / f"a.{ext}")
    _, top = tracemalloc.get_traced_memory()
    tracemalloc.stop()
    np.testing.assert_allclose(cloud.xyz + cloud.offset, xyz, atol=1e-4)
    assert top < 8 * cloud.xyz.nbytes  # its text, or its lines, cost far more


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
