"""Several clouds moved into one frame and written as one LAS/LAZ, a chunk at a time."""

from __future__ import annotations

import numpy as np
import pytest

from amrst import io
from amrst.errors import InvalidInput
from amrst.io import las_write
from amrst.types import Cloud, make_transform


def _turn(deg: float, shift: tuple[float, float, float]) -> np.ndarray:
    a = np.radians(deg)
    R = np.array([[np.cos(a), -np.sin(a), 0], [np.sin(a), np.cos(a), 0], [0, 0, 1]])
    return make_transform(R, np.asarray(shift, float))


@pytest.mark.parametrize("name", ["plot.laz", "plot.las"])
def test_moved_parts_are_one_file_with_their_scan_ids(
    tmp_path, monkeypatch: pytest.MonkeyPatch, name: str
) -> None:
    monkeypatch.setattr(las_write, "CHUNK_POINTS", 700)  # several chunks a part
    rng = np.random.default_rng(0)
    offset = np.array([512_000.0, 4_200_000.0, 300.0])  # georeferenced reference
    a = Cloud(
        rng.uniform(-20, 20, (2_000, 3)),
        offset=offset,
        attributes={"intensity": rng.integers(0, 60_000, 2_000).astype(np.uint16)},
    )
    b = Cloud(
        rng.uniform(-20, 20, (1_500, 3)),
        offset=np.zeros(3),
        attributes={
            "intensity": rng.integers(0, 60_000, 1_500).astype(np.uint16),
            "only_here": np.ones(1_500),
        },
    )
    moves = [np.eye(4), _turn(30.0, (4.0, -2.0, 0.5))]
    path = tmp_path / name
    io.write_merged(path, [a, b], moves, offset, [1, 2])
    back = io.read(path)
    world = back.xyz + back.offset
    expect = np.vstack(
        [a.xyz + offset, b.xyz @ moves[1][:3, :3].T + moves[1][:3, 3] + offset]
    )
    assert np.abs(world - expect).max() < 1e-4  # 0.1 mm
    assert np.array_equal(back.attributes["scan_id"], np.r_[[1] * 2_000, [2] * 1_500])
    # LAS tools (CloudCompare, LAStools, lidR) tell merged scans by point_source_id.
    import laspy

    ids = np.asarray(laspy.read(path).point_source_id)
    assert np.array_equal(ids, back.attributes["scan_id"])
    expect_i = np.r_[a.attributes["intensity"], b.attributes["intensity"]]
    assert np.array_equal(back.attributes["intensity"], expect_i)
    assert "only_here" not in back.attributes  # kept only when every part has it


def test_parts_loaded_as_written_are_planned_from_their_samples(
    tmp_path, monkeypatch: pytest.MonkeyPatch, caplog: pytest.LogCaptureFixture
) -> None:
    monkeypatch.setattr(las_write, "CHUNK_POINTS", 700)
    rng = np.random.default_rng(2)
    offset = np.array([512_000.0, 4_200_000.0, 300.0])
    values = [rng.integers(0, 60_000, n).astype(np.int64) for n in (2_000, 1_500)]
    values[1][7] = 70_000  # not in its sample, past uint16
    whole = [
        Cloud(rng.uniform(-20, 20, (len(v), 3)), offset, {"intensity": v})
        for v in values
    ]
    samples = [c.select(np.arange(0, len(c), 10)) for c in whole]
    loaded = []

    def load(k: int) -> Cloud:
        loaded.append(k)
        return whole[k]

    moves = [np.eye(4), _turn(30.0, (4.0, -2.0, 0.5))]
    path = tmp_path / "plot.laz"
    io.write_merged(path, samples, moves, offset, [1, 2], load=load)
    assert loaded == [0, 1]  # each part loaded once, as it is written
    back = io.read(path)
    expect = np.vstack(
        [c.xyz @ T[:3, :3].T + T[:3, 3] for c, T in zip(whole, moves, strict=True)]
    )
    assert np.abs(back.xyz + back.offset - (expect + offset)).max() < 1e-4
    assert np.bincount(back.attributes["scan_id"]).tolist() == [0, 2_000, 1_500]
    assert back.attributes["intensity"][2_007] == 65_535  # clipped, and said so
    assert "intensity: values the LAS field cannot hold" in caplog.text


def test_a_merged_cloud_needs_a_las_name(tmp_path) -> None:
    c = Cloud(np.zeros((3, 3)))
    with pytest.raises(InvalidInput, match=r"\.laz or \.las"):
        io.write_merged(tmp_path / "plot.ply", [c], [np.eye(4)], np.zeros(3), [1])
    with pytest.raises(InvalidInput, match="does not exist"):
        io.write_merged(tmp_path / "no" / "p.laz", [c], [np.eye(4)], np.zeros(3), [1])


def test_values_a_standard_field_cannot_hold_are_kept_exactly(tmp_path) -> None:
    # A float intensity (0..1) in parts with two different offsets: the LAS field
    # gets the rounded values, amrst_intensity the exact ones, as io.write keeps them.
    rng = np.random.default_rng(1)
    parts = [
        Cloud(
            rng.uniform(-5, 5, (400, 3)),
            offset=np.array([512_000.0, 4_200_000.0, 300.0]),
            attributes={"intensity": rng.uniform(0, 1, 400)},
        ),
        Cloud(
            rng.uniform(-5, 5, (300, 3)),
            offset=np.array([512_010.0, 4_199_990.0, 301.0]),
            attributes={"intensity": rng.uniform(0, 1, 300)},
        ),
    ]
    moves = [np.eye(4), _turn(-15.0, (1.0, 2.0, 0.0))]
    world = np.array([512_000.0, 4_200_000.0, 300.0])
    # A part's move takes its own local frame into the reference's: here the second
    # part's offset differs from the reference's by (10, -10, 1).
    moves[1] = moves[1] @ make_transform(np.eye(3), parts[1].offset - world)
    path = tmp_path / "plot.laz"
    io.write_merged(path, parts, moves, world, [1, 7])
    back = io.read(path)
    expect = np.vstack(
        [
            parts[0].xyz + world,
            (parts[1].xyz + parts[1].offset - world) @ moves[1][:3, :3].T
            + _turn(-15.0, (1.0, 2.0, 0.0))[:3, 3]
            + world,
        ]
    )
    assert np.abs(back.xyz + back.offset - expect).max() < 1e-4
    exact = np.r_[parts[0].attributes["intensity"], parts[1].attributes["intensity"]]
    assert np.allclose(back.attributes["intensity"], exact)
    assert set(np.unique(back.attributes["scan_id"])) == {1, 7}


def test_labels_set_tree_and_ground_and_keep_the_classes_a_scan_set(tmp_path) -> None:
    # A scan's own classes (5 high vegetation, 40 beyond a 5-bit field) stay; what it
    # left unset (0 never classified, 1 unassigned) becomes ground (2) where the labels
    # say so, in the exact extra field amrst reads back too.
    xyz = np.c_[np.arange(8.0), np.zeros(8), np.zeros(8)]
    given = np.array([0, 1, 5, 40, 0, 1, 5, 40], dtype=np.uint8)
    part = Cloud(xyz, attributes={"classification": given})

    def labels(moved: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        return (moved[:, 0] >= 4).astype(np.uint32) * 3, moved[:, 0] < 4

    path = tmp_path / "plot.laz"
    io.write_merged(path, [part], [np.eye(4)], np.zeros(3), [1], labels=labels)
    back = io.read(path)
    order = np.argsort(back.xyz[:, 0])
    assert back.attributes["classification"][order].tolist() == [
        2,
        2,
        5,
        40,
        1,
        1,
        5,
        40,
    ]
    assert back.attributes["tree"][order].tolist() == [0, 0, 0, 0, 3, 3, 3, 3]
