"""E57 and PTX: several scans per file, poses, intensity, colour, georeferencing.

Files are made by the tests (pye57 writes real E57 through libE57Format) and read back
through the same entry points the CLI and the campaign use.
"""

from __future__ import annotations

import re

import numpy as np
import pytest
from _writers import write_e57, write_ptx
from scipy.spatial.transform import Rotation

from amrst import io
from amrst.errors import InvalidInput
from amrst.io.scans import (
    list_scans,
    names_several,
    one_scan_specs,
    read_scans,
    split_spec,
)
from amrst.types import Cloud, make_transform

WRITERS = {".e57": write_e57, ".ptx": write_ptx}
GEO = np.array([512345.678, 5456789.012, 310.5])


def _scans(n: int = 3, points: int = 400) -> tuple[list[Cloud], list[np.ndarray]]:
    rng = np.random.default_rng(1)
    scans, poses = [], []
    for k in range(n):
        attrs = {
            "intensity": rng.random(points).astype(np.float32),
            "red": rng.integers(0, 256, points).astype(np.uint8),
            "green": rng.integers(0, 256, points).astype(np.uint8),
            "blue": rng.integers(0, 256, points).astype(np.uint8),
        }
        scans.append(
            Cloud(rng.normal(size=(points, 3)) * 4, attributes=attrs, name=f"s{k}")
        )
        R = Rotation.from_euler("zyx", [40 * k, 0.5 * k, -0.3 * k], degrees=True)
        poses.append(
            make_transform(R.as_matrix(), GEO + np.array([3.0 * k, -2.0 * k, 0.1 * k]))
        )
    return scans, poses


@pytest.mark.parametrize("ext", [".e57", ".ptx"])
def test_round_trip_several_scans_posed_and_local(tmp_path, ext):
    scans, poses = _scans()
    path = tmp_path / f"plot{ext}"
    WRITERS[ext](path, scans, poses)
    infos = list_scans(path)
    assert [i.n_points for i in infos] == [400, 400, 400]
    assert infos[1].fields == ("intensity", "red", "green", "blue")
    np.testing.assert_allclose(infos[2].T_world_scanner, poses[2], atol=1e-9)
    tol = 1e-5 if ext == ".e57" else 1e-9  # pye57 stores scanner xyz as float32
    for k in range(3):
        (cloud,) = read_scans(f"{path}#{k}")
        assert cloud.name == f"plot{ext}#{k}"
        expected = scans[k].xyz @ poses[k][:3, :3].T + poses[k][:3, 3]
        # georeferenced: big offset, small local values, sub-millimetre world error
        assert np.all(cloud.offset[:2] > 1e5)
        assert np.abs(cloud.xyz).max() < 1e4
        np.testing.assert_allclose(cloud.world_xyz, expected, rtol=0, atol=tol)
        np.testing.assert_allclose(cloud.intensity, scans[k].intensity, atol=1e-6)
        for c in ("red", "green", "blue"):
            assert np.array_equal(cloud.attributes[c], scans[k].attributes[c])
        np.testing.assert_allclose(cloud.meta["scanner_origin"], poses[k][:3, 3])
        (local,) = read_scans(f"{path}#{k}", posed=False)
        np.testing.assert_allclose(local.world_xyz, scans[k].xyz, atol=tol)
        np.testing.assert_allclose(np.array(local.meta["pose"]), poses[k], atol=1e-9)
    two = read_scans(f"{path}#2,0")
    assert [c.meta["scan_index"] for c in two] == [2, 0]
    merged = io.read(path)  # the amrst.io entry: every scan posed, with scan_id
    assert len(merged) == 1200
    assert np.bincount(merged.attributes["scan_id"]).tolist() == [400, 400, 400]


def test_ptx_drops_points_without_return(tmp_path):
    xyz = np.array([[1.0, 2.0, 3.0], [0.0, 0.0, 0.0], [4.0, 5.0, 6.0], [7.0, 1.0, 2.0]])
    write_ptx(tmp_path / "a.ptx", [Cloud(xyz)])
    (cloud,) = read_scans(tmp_path / "a.ptx")
    assert len(cloud) == 3
    assert cloud.meta["n_no_return"] == 1


def test_ptx_written_registered_keeps_its_scanner_where_the_header_puts_it(tmp_path):
    # An identity matrix and a scanner position: the points are already registered.
    head = ["3", "1", "5 6 1.5", "1 0 0", "0 1 0", "0 0 1"]
    head += ["1 0 0 0", "0 1 0 0", "0 0 1 0", "0 0 0 1"]
    points = ["6 6 1.5 0.5", "5 7 2 0.5", "4 6 1 0.5"]
    (tmp_path / "r.ptx").write_text("\n".join(head + points) + "\n")
    for posed in (True, False):
        (cloud,) = read_scans(tmp_path / "r.ptx", posed=posed)
        np.testing.assert_allclose(cloud.world_xyz[0], (6, 6, 1.5))
        assert cloud.meta["scanner_origin"] == (5.0, 6.0, 1.5)
    (info,) = list_scans(tmp_path / "r.ptx")  # amrst info says where it stood
    assert info.scanner_xyz == (5.0, 6.0, 1.5)


_IDENTITY = "1 0 0 0|0 1 0 0|0 0 1 0|0 0 0 1"


@pytest.mark.parametrize(
    ("size", "scanner", "matrix", "says"),
    [
        ("3 1", "nan 6 1.5", _IDENTITY, "scanner position"),
        ("3 1", "1e12 0 0", _IDENTITY, "scanner position"),
        ("3 1", "0 0 0", "2 0 0 0|0 2 0 0|0 0 2 0|0 0 0 1", "is not a rotation"),
        ("3 1", "0 0 0", "0 0 0 0|0 0 0 0|0 0 0 0|0 0 0 1", "is not a rotation"),
        ("3 1", "0 0 0", "1 0 0 0|0 1 0 0|0 0 1 0|1e12 0 0 1", r"beyond 1e\+09 m"),
        ("99999999999 99999999999", "0 0 0", _IDENTITY, "more points than a scan"),
    ],
)
def test_ptx_header_that_cannot_be_a_scanner_is_refused(
    tmp_path, size, scanner, matrix, says
):
    head = [*size.split(), scanner, "1 0 0", "0 1 0", "0 0 1", *matrix.split("|")]
    points = ["6 6 1.5 0.5", "5 7 2 0.5", "4 6 1 0.5"]
    (tmp_path / "r.ptx").write_text("\n".join(head + points) + "\n")
    with pytest.raises(InvalidInput, match=says):
        read_scans(tmp_path / "r.ptx")
    if "more points" in says:  # the file cannot even be walked
        with pytest.raises(InvalidInput, match=says):
            list_scans(tmp_path / "r.ptx")


def test_a_bad_pose_refuses_that_scan_only(tmp_path, capsys):
    from amrst.cli import main

    scans, poses = _scans(3, 50)
    poses[1] = poses[1].copy()
    poses[1][:3, :3] *= 2.0  # a scale, as a corrupt quaternion gives
    path = tmp_path / "p.ptx"
    write_ptx(path, scans, poses)
    assert len(list_scans(path)) == 3
    assert len(read_scans(f"{path}#2")) == 1
    with pytest.raises(InvalidInput, match="is not a rotation"):
        read_scans(f"{path}#1")
    assert main(["info", str(path)]) == 0  # lists them, and says which
    lines = capsys.readouterr().out.splitlines()
    assert "pose not usable" in lines[3]
    assert "pose not usable" not in lines[2] + lines[4]


def test_a_stored_pose_must_be_a_rotation_and_a_position():
    from amrst.io.posed import check_pose

    T = np.eye(4)
    T[:3, 3] = (512_000.0, 5_403_000.0, 310.0)
    np.testing.assert_array_equal(check_pose(T, "a.e57#0"), T)
    zero = np.eye(4)
    zero[:3, :3] = 0.0  # what a zero quaternion gives
    mirrored = np.diag([1.0, 1.0, -1.0, 1.0])
    for bad in (zero, mirrored, np.full((4, 4), np.nan)):
        with pytest.raises(InvalidInput, match=r"a\.e57#1: the scan's stored pose"):
            check_pose(bad, "a.e57#1")


def test_spec_syntax():
    assert split_spec("a/plot.e57#0, 2") == (split_spec("a/plot.e57")[0], (0, 2))
    assert split_spec("tree.laz")[1] is None
    with pytest.raises(InvalidInput, match="scan numbers"):
        split_spec("plot.e57#two")


@pytest.mark.parametrize("ext", [".e57", ".ptx"])
def test_a_spec_splits_into_one_spec_per_scan(tmp_path, ext):
    scans, poses = _scans(3, 50)
    path = tmp_path / f"p{ext}"
    WRITERS[ext](path, scans, poses)
    # E57 keeps each scan's name (the writer stores the cloud's); PTX has none.
    names = [f"s{k}" if ext == ".e57" else "" for k in range(3)]
    assert one_scan_specs([str(path)]) == [(f"{path}#{k}", names[k]) for k in range(3)]
    assert one_scan_specs([f"{path}#2,0"]) == [
        (f"{path}#2", names[2]),
        (f"{path}#0", names[0]),
    ]
    assert one_scan_specs([f"{path}#1"]) == [(f"{path}#1", names[1])]
    for spec, _name in one_scan_specs([str(path)]):
        assert len(read_scans(spec)) == 1
    WRITERS[ext](tmp_path / f"one{ext}", scans[:1], poses[:1])
    one = str(tmp_path / f"one{ext}")
    assert one_scan_specs([one]) == [(one, names[0])]
    tree = str(tmp_path / "tree.ply")
    io.write(tree, scans[0])
    assert one_scan_specs([tree]) == [(tree, "")]
    with pytest.raises(InvalidInput, match="no scan 5"):  # before any point is read
        one_scan_specs([f"{path}#0,5"])
    with pytest.raises(InvalidInput, match="File not found"):
        one_scan_specs([tmp_path / "no_such_tree.laz"])


def test_one_scan_of_a_ptx_is_read_without_walking_the_scans_after_it(tmp_path):
    scans, poses = _scans(3, 40)
    path = tmp_path / "three.ptx"
    write_ptx(path, scans, poses)
    lines = path.read_text().splitlines()
    lines[2 * (10 + 40)] = "not a count"  # the last scan's header, broken
    path.write_text("\n".join(lines) + "\n")
    (first,) = read_scans(f"{path}#0")
    assert len(first) == 40
    with pytest.raises(InvalidInput, match="export it again"):
        list_scans(path)  # a run lists every scan first, and refuses the file


def test_a_file_named_by_several_specs_is_listed_once(tmp_path, monkeypatch):
    from amrst.io import scans as scans_module

    scans, poses = _scans(3, 50)
    path = tmp_path / "p.ptx"
    write_ptx(path, scans, poses)
    listed = []
    list_file = scans_module.list_scans
    monkeypatch.setattr(
        scans_module, "list_scans", lambda p: listed.append(p) or list_file(p)
    )
    specs = [f"{path}#{k}" for k in (2, 0, 1)]
    assert [spec for spec, _name in one_scan_specs(specs)] == specs
    assert listed == [path]


@pytest.mark.parametrize("ext", [".e57", ".ptx"])
def test_scan_number_out_of_range(tmp_path, ext):
    scans, poses = _scans(2, 50)
    WRITERS[ext](tmp_path / f"p{ext}", scans, poses)
    with pytest.raises(InvalidInput, match=r"holds 2 scan.*no scan 5"):
        read_scans(f"{tmp_path / f'p{ext}'}#5")


def test_an_empty_scan_is_named_in_the_refusal(tmp_path):
    scans, poses = _scans(1, 50)
    path = tmp_path / "p.ptx"
    write_ptx(path, [scans[0], Cloud(np.zeros((0, 3)))], poses * 2)
    expected = f"^scan #1 of {re.escape(str(path))} contains no points"
    with pytest.raises(InvalidInput, match=expected):
        read_scans(f"{path}#1")


@pytest.mark.parametrize("ext", [".e57", ".ptx"])
def test_truncated_and_garbage_files_one_line(tmp_path, ext):
    scans, poses = _scans(2, 300)
    good = tmp_path / f"good{ext}"
    WRITERS[ext](good, scans, poses)
    data = good.read_bytes()
    cut = tmp_path / f"cut{ext}"
    cut.write_bytes(data[: len(data) * 2 // 3])
    junk = tmp_path / f"junk{ext}"
    junk.write_bytes(b"\x00\x17 not a scan file \xff" * 50)
    for bad in (cut, junk):
        for read in (io.read, read_scans, list_scans):
            with pytest.raises(InvalidInput) as info:
                read(bad)
            message = str(info.value)
            assert "\n" not in message
            assert bad.name in message
            assert "export it again" in message.lower()


def test_one_scan_of_a_ptx_is_read_without_holding_the_others(tmp_path):
    import tracemalloc

    scans, poses = _scans(5, 20_000)
    write_ptx(tmp_path / "five.ptx", scans, poses)
    write_ptx(tmp_path / "one.ptx", scans[:1], poses[:1])

    def peak(spec: str) -> int:
        tracemalloc.start()
        (cloud,) = read_scans(spec)
        _, top = tracemalloc.get_traced_memory()
        tracemalloc.stop()
        assert len(cloud) == 20_000
        return top

    # The file is text: a reader that took it whole would hold all five scans.
    assert peak(f"{tmp_path / 'five.ptx'}#0") < 1.5 * peak(str(tmp_path / "one.ptx"))
    lines = (tmp_path / "five.ptx").read_text().splitlines()
    one_point = ["1", "1", *lines[2:10], "1 2", ""]  # a point of two numbers
    (tmp_path / "bad_width.ptx").write_text("\n".join(one_point))
    with pytest.raises(InvalidInput, match=r"line 11: a PTX point line has 3, 4 or 7"):
        read_scans(tmp_path / "bad_width.ptx")


def test_a_ptx_scan_is_read_holding_its_numbers_not_its_lines(tmp_path):
    import tracemalloc

    scans, poses = _scans(1, 50_000)
    write_ptx(tmp_path / "one.ptx", scans, poses)
    tracemalloc.start()
    (cloud,) = read_scans(tmp_path / "one.ptx")
    _, top = tracemalloc.get_traced_memory()
    tracemalloc.stop()
    assert len(cloud) == 50_000
    # Its points as float64 and a few copies of them; a line held as a Python string,
    # or its numbers split into strings, costs several times more.
    assert top < 8 * cloud.xyz.nbytes


def test_a_ptx_with_a_blank_line_among_its_points_is_refused_by_every_reader(
    tmp_path,
):
    scans, poses = _scans(2, 30)
    write_ptx(tmp_path / "two.ptx", scans, poses)
    lines = (tmp_path / "two.ptx").read_text().splitlines()
    lines.insert(15, "")  # among the first scan's points
    bad = tmp_path / "blank.ptx"
    bad.write_text("\n".join(lines) + "\n")
    for read in (read_scans, list_scans, lambda p: read_scans(f"{p}#1")):
        with pytest.raises(InvalidInput, match="corrupt") as info:
            read(bad)
        assert "\n" not in str(info.value)
    # A header that declares more points than the file could hold is truncated.
    lines = (tmp_path / "two.ptx").read_text().splitlines()
    lines[0] = "3000000000"
    (tmp_path / "huge.ptx").write_text("\n".join(lines) + "\n")
    with pytest.raises(InvalidInput, match="truncated"):
        read_scans(tmp_path / "huge.ptx")


def test_names_several_tells_the_specs_that_may_hold_several_scans():
    assert names_several("plot.e57")
    assert names_several("plot.PTX")
    assert names_several("plot.e57#0,2")
    assert not names_several("plot.e57#1")
    assert not names_several("scan.laz")
    assert not names_several("a#b.ply")


def test_empty_and_missing(tmp_path):
    (tmp_path / "e.e57").write_bytes(b"")
    with pytest.raises(InvalidInput, match="is empty"):
        read_scans(tmp_path / "e.e57")
    with pytest.raises(InvalidInput, match="File not found"):
        read_scans(tmp_path / "none.ptx#1")
    io.write(tmp_path / "x.ply", Cloud(np.zeros((5, 3))))
    with pytest.raises(InvalidInput, match="holds one scan"):
        read_scans(f"{tmp_path / 'x.ply'}#1")


@pytest.mark.parametrize("ext", [".e57", ".ptx"])
def test_info_lists_the_scans_of_a_file_and_describes_one(tmp_path, capsys, ext):
    from amrst.cli import main

    scans, poses = _scans()
    path = tmp_path / f"plot{ext}"
    WRITERS[ext](path, scans, poses)
    assert main(["info", str(path)]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert lines[0] == f"plot{ext}: 3 scans, 1,200 points"
    assert [ln.split()[0] for ln in lines[2:5]] == ["#0", "#1", "#2"]
    # Where scan 2's scanner stood, in the file's (georeferenced) coordinates.
    assert "  ".join(f"{v:.3f}" for v in poses[2][:3, 3]) in lines[4]
    assert main(["info", f"{path}#2"]) == 0
    out = capsys.readouterr().out
    assert out.startswith(f"plot{ext}#2\n")
    assert "points      400" in out
    assert main(["info", f"{path}#3"]) == 2
    assert "there is no scan 3" in capsys.readouterr().err
