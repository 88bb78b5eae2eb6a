"""Bad LAS/LAZ headers: counts that cannot fit, garbage after the signature, bad
scales, data beyond the file, records that disagree with the header's bounds.

Each is refused at once with an InvalidInput (laspy alone can loop on some); odd but
valid files still read.
"""

from __future__ import annotations

import struct
import subprocess
import sys

import numpy as np
import pytest
from _clouds import GEO_OFFSET
from _clouds import small_cloud as make_small_cloud

from amrst import io
from amrst.errors import InvalidInput
from amrst.types import Cloud


@pytest.fixture
def small_cloud() -> Cloud:
    return make_small_cloud()


def _valid_las(tmp_path, cloud: Cloud, ext: str = ".las") -> bytearray:
    io.write(tmp_path / f"valid{ext}", cloud)
    return bytearray((tmp_path / f"valid{ext}").read_bytes())


@pytest.mark.timeout(30)  # laspy alone can loop on these
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


@pytest.mark.parametrize("ext", [".las", ".laz"])
@pytest.mark.parametrize(
    ("pos", "byte", "message"),
    [
        (138, 0x7F, r"scale factor is 1\.79769e\+304 for x"),
        (137, 0xFF, r"scale factor is 1\.9509 for x"),  # points kilometres apart
        (138, 0x00, r"scale factor is 3\.64556e-308 for x"),
        (162, 0x7F, r"offset is 5\.48612e\+303 for x"),
        (170, 0xFF, r"offset is -5\.48612e\+303 for y"),
        (178, 0x7F, r"offset is 5\.48612e\+303 for z"),
    ],
)
def test_las_scale_or_offset_no_scanner_writes_is_refused(
    tmp_path, small_cloud, ext, pos, byte, message
):
    data = _valid_las(tmp_path, small_cloud, ext)
    data[pos] = byte
    (tmp_path / f"s{ext}").write_bytes(data)
    with pytest.raises(InvalidInput, match=message) as caught:
        io.read(tmp_path / f"s{ext}")
    assert "\n" not in str(caught.value)


def test_las_scales_and_offsets_real_files_use_still_read(tmp_path):
    import laspy

    header = laspy.LasHeader(point_format=3, version="1.2")
    header.scales, header.offsets = [1e-7, 0.001, 1.0], [0.0, 5_000_000.0, -100.0]
    las = laspy.LasData(header)
    las.x, las.y, las.z = np.array([[0.5, 1.5], [5e6 + 1, 5e6 + 2], [3.0, 4.0]])
    las.write(tmp_path / "r.las")
    cloud = io.read(tmp_path / "r.las")
    world = [[0.5, 5e6 + 1, 3.0], [1.5, 5e6 + 2, 4.0]]
    np.testing.assert_allclose(cloud.xyz + cloud.offset, world)
    far = Cloud(cloud.xyz, np.array([9e8, 0.0, 0.0]))  # coordinates go to 1e9 m
    io.write(tmp_path / "far.las", far)
    assert io.read(tmp_path / "far.las").offset[0] == 9e8


@pytest.mark.parametrize("ext", [".las", ".laz"])
@pytest.mark.parametrize(("byte", "shown"), [(0x7F, 127), (0xFF, 127), (0x8B, 11)])
def test_las_point_format_beyond_the_standard_is_refused(
    tmp_path, small_cloud, ext, byte, shown
):
    data = _valid_las(tmp_path, small_cloud, ext)
    data[104] = byte  # bit 7 only marks the points as compressed (LAZ)
    (tmp_path / f"f{ext}").write_bytes(data)
    with pytest.raises(
        InvalidInput, match=f"point format {shown} is not a LAS point format"
    ):
        io.read(tmp_path / f"f{ext}")


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


@pytest.mark.timeout(30)
def test_laz_chunk_table_counting_more_chunks_than_bytes_is_refused(
    tmp_path, small_cloud
):
    # lazrs allocates the table for the count it finds and aborts the process when
    # that fails: the count is checked against the bytes the chunks can take.
    data = _valid_las(tmp_path, small_cloud, ".laz")
    _, point_start, _ = struct.unpack_from("<HII", data, 94)
    (table_start,) = struct.unpack_from("<q", data, point_start)
    struct.pack_into("<I", data, table_start + 4, 2_373_713_921)
    (tmp_path / "t.laz").write_bytes(data)
    with pytest.raises(InvalidInput, match="corrupt LAZ chunk table: it lists 2,373"):
        io.read(tmp_path / "t.laz")


def _laz_vlr_data_at(data: bytearray) -> int:
    """Where the LASzip VLR's payload starts."""
    pos, _, n_vlrs = struct.unpack_from("<HII", data, 94)
    for _ in range(n_vlrs):
        (length,) = struct.unpack_from("<H", data, pos + 20)
        if data[pos + 2 : pos + 16] == b"laszip encoded":
            return pos + 54
        pos += 54 + length
    raise AssertionError("no LASzip VLR")


@pytest.mark.timeout(60)
@pytest.mark.parametrize(
    ("offset", "fmt", "value", "message"),
    [
        (12, "<I", 2_868_953_936, "chunk size is 2,868,953,936 points"),  # fuzz seed 61
        (2, "<H", 44, "its coder is 44"),
        (0, "<H", 190, "its compressor is 190"),
        (38, "<H", 34, "unknown version 34"),
        (36, "<H", 21, "has size 21, not 20"),
    ],
)
def test_laz_corrupt_compression_record_is_refused_not_an_abort(
    tmp_path, small_cloud, offset, fmt, value, message
):
    """lazrs's parallel decoder aborted the whole process on such files (an
    allocation of chunk size x record length); the check runs in a child here so
    a regression fails this test instead of killing the suite."""
    data = _valid_las(tmp_path, small_cloud, ".laz")
    struct.pack_into(fmt, data, _laz_vlr_data_at(data) + offset, value)
    bad = tmp_path / "bad.laz"
    bad.write_bytes(data)
    code = (
        "import sys\nfrom amrst import io\nfrom amrst.errors import InvalidInput\n"
        "try:\n    io.read(sys.argv[1])\nexcept InvalidInput as e:\n"
        "    print(e)\n    sys.exit(2)\n"
    )
    proc = subprocess.run(
        [sys.executable, "-c", code, str(bad)],
        capture_output=True,
        text=True,
        timeout=50,
    )
    assert proc.returncode == 2, proc.stderr[-2000:]
    assert "corrupt LAZ compression record" in proc.stdout
    assert message in proc.stdout


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
