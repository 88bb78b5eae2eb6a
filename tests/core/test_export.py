"""Export: every part written atomically and read back with amrst.io."""

from __future__ import annotations

import csv
import json
from pathlib import Path

import numpy as np
import pytest

from amrst import io
from amrst.errors import AmrstError, InvalidInput
from amrst.params import RegistrationParams, load_params
from amrst.results.export import PARTS, export_registration, merge_moved
from amrst.types import Cloud, make_transform

OFFSET = np.array([500000.0, 5000000.0, 100.0])
SOURCE_OFFSET = OFFSET + np.array([10.0, -5.0, 0.0])


def _rot_z(deg: float) -> np.ndarray:
    a = np.radians(deg)
    return np.array([[np.cos(a), -np.sin(a), 0], [np.sin(a), np.cos(a), 0], [0, 0, 1]])


@pytest.fixture
def scans() -> tuple[Cloud, Cloud, np.ndarray]:
    """Target with intensity, source with colour: each has a field the other lacks.
    Both georeferenced; T_target_source maps source world into target world."""
    rng = np.random.default_rng(0)
    target = Cloud(
        rng.uniform(0, 5, (300, 3)),
        OFFSET,
        {"intensity": rng.integers(1, 60000, 300).astype(np.uint16)},
        "target.ply",
    )
    source = Cloud(
        rng.uniform(0, 5, (200, 3)),
        SOURCE_OFFSET,
        {"red": rng.integers(1, 255, 200).astype(np.uint8)},
        "source.ply",
    )
    R = _rot_z(30.0)
    T = make_transform(R, SOURCE_OFFSET - R @ OFFSET + np.array([0.5, 0.25, 0.1]))
    return target, source, T


def _moved_world(T: np.ndarray, source: Cloud, origin: np.ndarray) -> np.ndarray:
    """T applied to the source world points, relative to ``origin`` (no large sums)."""
    R = T[:3, :3]
    return source.xyz @ R.T + (R @ source.offset + T[:3, 3] - origin)


def test_all_parts_are_written_and_read_back(tmp_path: Path, scans) -> None:
    target, source, T = scans
    T_coarse = make_transform(np.eye(3), [1.0, 2.0, 3.0]) @ T
    metrics = {"fine": {"rmse_m": 0.01, "converged": True}, "score": 0.9}
    params = RegistrationParams()
    files = export_registration(
        tmp_path / "out",
        target=target,
        source=source,
        T_target_source=T,
        T_coarse=T_coarse,
        metrics=metrics,
        params=params,
        transform_extra={"confidence": 0.7},
    )
    out = tmp_path / "out"
    names = sorted(p.name for p in out.iterdir())
    assert names == sorted(
        [
            "registered_source.ply",
            "merged.ply",
            "transform.json",
            "transform.txt",
            "metrics.json",
            "metrics.csv",
            "params.json",
        ]
    ), "missing parts, or temp files left behind"
    assert sorted(p.name for p in files) == names

    merged = io.read(out / "merged.ply")
    assert len(merged) == len(target) + len(source)
    scan_id = np.asarray(merged.attributes["scan_id"])
    assert set(np.unique(scan_id).tolist()) == {0, 1}
    assert np.count_nonzero(scan_id == 0) == len(target)
    # Geometry: target as it was, source moved by T (world coordinates, to 0.1 mm).
    np.testing.assert_allclose(
        merged.world_xyz[scan_id == 0] - OFFSET, target.world_xyz - OFFSET, atol=1e-4
    )
    np.testing.assert_allclose(
        merged.world_xyz[scan_id == 1] - OFFSET,
        _moved_world(T, source, OFFSET),
        atol=1e-4,
    )
    # Fields present in only one scan: kept, zeros for the other scan's points.
    intensity = np.asarray(merged.attributes["intensity"])
    red = np.asarray(merged.attributes["red"])
    np.testing.assert_array_equal(
        intensity[scan_id == 0], target.attributes["intensity"]
    )
    assert np.all(intensity[scan_id == 1] == 0)
    np.testing.assert_array_equal(red[scan_id == 1], source.attributes["red"])
    assert np.all(red[scan_id == 0] == 0)

    registered = io.read(out / "registered_source.ply")
    assert len(registered) == len(source)
    np.testing.assert_allclose(
        registered.world_xyz - OFFSET, _moved_world(T, source, OFFSET), atol=1e-4
    )
    np.testing.assert_array_equal(
        registered.attributes["red"], source.attributes["red"]
    )

    doc = json.loads((out / "transform.json").read_text(encoding="utf-8"))
    np.testing.assert_array_equal(np.asarray(doc["T_target_source"]), T)
    np.testing.assert_array_equal(np.asarray(doc["T_coarse"]), T_coarse)
    assert doc["confidence"] == 0.7
    assert (doc["target"], doc["source"]) == ("target.ply", "source.ply")
    T_txt = np.loadtxt(out / "transform.txt")
    assert T_txt.shape == (4, 4)
    np.testing.assert_allclose(T_txt, T, rtol=1e-11, atol=1e-9)

    assert json.loads((out / "metrics.json").read_text(encoding="utf-8")) == metrics
    with open(out / "metrics.csv", newline="", encoding="utf-8") as fh:
        rows = list(csv.reader(fh))
    assert rows[0] == ["metric", "value"]
    assert ["fine.rmse_m", "0.01"] in rows
    assert ["score", "0.9"] in rows
    loaded = load_params(out / "params.json")
    assert json.loads((out / "params.json").read_text())["schema_version"] == 1
    assert loaded.fine == params.fine


def test_merge_moved_directly(scans) -> None:
    target, source, _ = scans
    moved = Cloud(source.xyz, target.offset, source.attributes)
    merged = merge_moved(target, [(0, target), (1, moved)])
    assert len(merged) == 500
    assert merged.attributes["scan_id"].dtype == np.uint16
    assert merged.attributes["intensity"].dtype == np.uint16
    np.testing.assert_array_equal(merged.xyz[:300], target.xyz)
    np.testing.assert_array_equal(merged.xyz[300:], source.xyz)


def test_only_the_chosen_parts_are_written(tmp_path: Path, scans) -> None:
    target, source, T = scans
    files = export_registration(
        tmp_path, target=target, source=source, T_target_source=T, parts=("transform",)
    )
    assert sorted(p.name for p in files) == ["transform.json", "transform.txt"]
    assert sorted(p.name for p in tmp_path.iterdir()) == [
        "transform.json",
        "transform.txt",
    ]


@pytest.mark.parametrize("fmt", ["las", "pcd"])
def test_other_cloud_formats(tmp_path: Path, scans, fmt: str) -> None:
    target, source, T = scans
    export_registration(
        tmp_path,
        target=target,
        source=source,
        T_target_source=T,
        cloud_format=fmt,
        parts=("merged",),
    )
    merged = io.read(tmp_path / f"merged.{fmt}")
    assert len(merged) == 500
    assert set(np.unique(merged.attributes["scan_id"]).tolist()) == {0, 1}


def test_unknown_part_or_format_is_refused(tmp_path: Path, scans) -> None:
    target, source, T = scans
    with pytest.raises(InvalidInput, match="thumbnail"):
        export_registration(
            tmp_path,
            target=target,
            source=source,
            T_target_source=T,
            parts=("thumbnail",),
        )
    with pytest.raises(InvalidInput, match="'e57'"):
        export_registration(
            tmp_path,
            target=target,
            source=source,
            T_target_source=T,
            cloud_format="e57",
        )
    assert list(tmp_path.iterdir()) == []  # refused before writing anything
    assert set(PARTS) == {"registered", "merged", "transform", "metrics", "params"}


def test_failed_write_keeps_the_earlier_export(
    tmp_path: Path, scans, monkeypatch
) -> None:
    """Atomic: a writer that fails halfway leaves the old file intact and no temp."""
    target, source, T = scans
    export_registration(tmp_path, target=target, source=source, T_target_source=T)
    before = {p.name: p.read_bytes() for p in tmp_path.iterdir()}

    def broken(path, cloud, *, binary=True):
        Path(path).write_bytes(b"ply\nformat binary_little_endian 1.0\n")  # half a file
        raise OSError("disk full")

    monkeypatch.setitem(io._WRITERS, ".ply", broken)
    T2 = make_transform(np.eye(3), [5.0, 0.0, 0.0]) @ T
    with pytest.raises(AmrstError, match="disk full"):
        export_registration(tmp_path, target=target, source=source, T_target_source=T2)
    after = {p.name: p.read_bytes() for p in tmp_path.iterdir()}
    assert after == before


def test_unwritable_folder_is_refused(tmp_path: Path, scans) -> None:
    target, source, T = scans
    blocker = tmp_path / "file"
    blocker.write_text("x")
    with pytest.raises(InvalidInput, match="Cannot create the export folder"):
        export_registration(
            blocker / "sub", target=target, source=source, T_target_source=T
        )


def test_exported_files_are_readable_by_others(tmp_path, sample_pair) -> None:
    # mkstemp alone makes owner-only (0600) files; a colleague must be able to read exports.
    import stat

    from amrst.results.export import export_registration

    files = export_registration(
        tmp_path / "out",
        target=sample_pair.target,
        source=sample_pair.source,
        T_target_source=np.eye(4),
        parts=("registered", "transform", "metrics", "params"),
    )
    for f in files:
        assert f.stat().st_mode & stat.S_IROTH, f"{f.name} is not readable by others"


def test_failed_cloud_write_leaves_no_new_file(
    tmp_path: Path, scans, monkeypatch
) -> None:
    """registered_source.ply is written, merged.ply fails: neither may stay behind."""
    target, source, T = scans
    out = tmp_path / "out"
    real = io._WRITERS[".ply"]

    def fails_on_merged(path, cloud, *, binary=True):
        if cloud.name == "merged":
            raise OSError("disk full")
        return real(path, cloud, binary=binary)

    monkeypatch.setitem(io._WRITERS, ".ply", fails_on_merged)
    with pytest.raises(AmrstError, match="disk full") as exc:
        export_registration(out, target=target, source=source, T_target_source=T)
    assert ".amrst-export-" not in str(exc.value)  # names the real destination
    assert f"{out / 'merged.ply'}" in str(exc.value)
    assert list(out.iterdir()) == []  # no new file, no staging folder


def test_a_folder_in_the_way_is_refused_before_writing(tmp_path: Path, scans) -> None:
    target, source, T = scans
    (tmp_path / "merged.ply").mkdir()
    with pytest.raises(InvalidInput, match=r"merged\.ply: a folder has that name"):
        export_registration(tmp_path, target=target, source=source, T_target_source=T)
    assert [p.name for p in tmp_path.iterdir()] == ["merged.ply"]


def test_stale_clouds_are_removed_only_when_asked(
    tmp_path: Path, scans, caplog
) -> None:
    target, source, T = scans
    export_registration(
        tmp_path, target=target, source=source, T_target_source=T, cloud_format="pcd"
    )
    (tmp_path / "merged_keep.ply").write_text("not an AMRST output name")
    parts = ("transform", "metrics", "params")
    export_registration(
        tmp_path, target=target, source=source, T_target_source=T, parts=parts
    )
    assert (tmp_path / "merged.pcd").is_file()  # the library default keeps them
    with caplog.at_level("WARNING", logger="amrst.results.export"):
        export_registration(
            tmp_path,
            target=target,
            source=source,
            T_target_source=T,
            parts=parts,
            remove_stale=True,
        )
    names = {p.name for p in tmp_path.iterdir()}
    assert not names & {"merged.pcd", "registered_source.pcd"}
    assert "merged_keep.ply" in names
    assert len(caplog.records) == 1
    assert {"registered_source.pcd", "merged.pcd"} <= set(
        caplog.records[0].getMessage().rsplit(": ", 1)[1].rstrip(".").split(", ")
    )
    # Only the clouds again: the transform and the rest of the earlier result go.
    export_registration(
        tmp_path,
        target=target,
        source=source,
        T_target_source=T,
        parts=("registered",),
        remove_stale=True,
    )
    names = {p.name for p in tmp_path.iterdir()}
    assert names == {"registered_source.ply", "merged_keep.ply"}


def test_output_folder_checks(tmp_path: Path) -> None:
    from amrst.results.export import check_output_dir, output_names

    with pytest.raises(InvalidInput, match="empty"):
        check_output_dir("")
    a_file = tmp_path / "f"
    a_file.write_text("x")
    with pytest.raises(InvalidInput, match="existing file"):
        check_output_dir(a_file)
    with pytest.raises(InvalidInput, match="is a file, not a folder"):
        check_output_dir(a_file / "sub")
    if Path("/proc/self").is_dir():
        with pytest.raises(InvalidInput, match="Cannot create the export folder"):
            check_output_dir("/proc/amrst-test/out")
    # A missing folder passes and is not left behind (nor its missing parents).
    assert check_output_dir(tmp_path / "a" / "b") == tmp_path / "a" / "b"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["f"]
    assert output_names(("params", "merged"), "las") == ["merged.las", "params.json"]


def test_params_json_is_strict_json(tmp_path: Path, scans) -> None:
    target, source, T = scans
    export_registration(
        tmp_path, target=target, source=source, T_target_source=T, parts=("params",)
    )
    text = (tmp_path / "params.json").read_text(encoding="utf-8")
    assert "NaN" not in text
    json.loads(text, parse_constant=lambda name: pytest.fail(f"{name} in params.json"))
    assert np.isnan(load_params(tmp_path / "params.json").separate.intensity_threshold)


def _no_constant(name: str) -> None:
    raise AssertionError(f"not strict JSON: {name}")


def test_output_json_is_strict_and_says_why_a_value_is_null(
    tmp_path: Path, scans
) -> None:
    """An infinite truth error is written to metrics.json as JSON (no ``Infinity``)."""
    target, source, T = scans
    metrics = {"truth": {"fine": {"translation_error_m": float("inf")}}, "ok": 1.0}
    export_registration(
        tmp_path,
        target=target,
        source=source,
        T_target_source=T,
        metrics=metrics,
        parts=("metrics", "transform"),
        transform_extra={"confidence": float("nan")},
    )
    for name in ("metrics.json", "transform.json"):
        text = (tmp_path / name).read_text(encoding="utf-8")
        # A strict parser: a bare NaN or Infinity fails the test.
        doc = json.loads(text, parse_constant=_no_constant)
        assert "null_values" in doc
    doc = json.loads((tmp_path / "metrics.json").read_text(encoding="utf-8"))
    assert doc["truth"]["fine"]["translation_error_m"] is None
    assert doc["null_values"]["truth.fine.translation_error_m"].startswith("inf (")
    assert doc["ok"] == 1.0
