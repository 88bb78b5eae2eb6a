"""Parameter files: round trips, the versioned v1 fixture, refusals, every preset."""

from __future__ import annotations

import dataclasses
import json
import math
from pathlib import Path

import pytest

from amrst.errors import InvalidInput
from amrst.params import (
    SCHEMA_VERSION,
    RegistrationParams,
    list_presets,
    load_params,
    load_preset,
    params_from_dict,
    params_to_dict,
    save_params,
)

DATA = Path(__file__).parent / "data"
PRESETS = Path(__file__).resolve().parents[2] / "resources" / "presets"


def _same(a: RegistrationParams, b: RegistrationParams) -> bool:
    """Equal parameters; NaN defaults (e.g. intensity_threshold) compare equal."""
    return json.dumps(params_to_dict(a), sort_keys=True) == json.dumps(
        params_to_dict(b), sort_keys=True
    )


def _changed() -> RegistrationParams:
    p = RegistrationParams()
    return dataclasses.replace(
        p,
        preprocess=dataclasses.replace(p.preprocess, voxel_size_m=0.035),
        separate=dataclasses.replace(p.separate, mode="geometry", scales_k=(8, 16, 32)),
        keypoints=dataclasses.replace(p.keypoints, max_depth=5),
        match=dataclasses.replace(p.match, levelled=False),
        fine=dataclasses.replace(p.fine, method="lm_icp", points="leaf"),
    )


def test_dict_round_trip() -> None:
    p = _changed()
    d = params_to_dict(p)
    assert d["schema_version"] == SCHEMA_VERSION == 1
    assert d["separate"]["scales_k"] == [8, 16, 32]  # JSON-ready lists
    json.dumps(d)  # serialisable
    back = params_from_dict(d)
    assert back == p  # same objects throughout: NaN is the same NaN
    assert back.separate.scales_k == (8, 16, 32)
    assert back.fine.method == "lm_icp"
    assert not _same(back, RegistrationParams())


def test_file_round_trip(tmp_path: Path) -> None:
    p = _changed()
    path = tmp_path / "params.json"
    save_params(path, p)
    back = load_params(path)
    assert _same(back, p)
    assert back.separate.scales_k == (8, 16, 32)
    assert back.keypoints.max_depth == 5
    assert back.match.levelled is False
    assert [f.name for f in tmp_path.iterdir()] == ["params.json"]  # no temp left


def test_v1_file_keeps_loading() -> None:
    """tests/core/data/params_v1.json: a schema 1 file with a few keys. Its values must
    apply; everything it does not name takes the current defaults."""
    path = DATA / "params_v1.json"
    raw = json.loads(path.read_text(encoding="utf-8"))
    assert raw["schema_version"] == 1
    p = load_params(path)
    given = {
        ("preprocess", "voxel_size_m"): 0.02,
        ("preprocess", "outlier_neighbours"): 12,
        ("separate", "mode"): "auto",
        ("separate", "scales_k"): (10, 30),
        ("skeleton", "points"): "all",
        ("skeleton", "bin_size_m"): 0.25,
        ("keypoints", "max_depth"): 50,
        ("keypoints", "merge_radius_m"): 0.3,
        ("match", "edge_tolerance"): 0.08,
        ("match", "levelled"): True,
        ("coarse", "verify_voxel_m"): 0.1,
        ("fine", "method"): "robust_plane",
        ("fine", "max_corr_dist_m"): 0.3,
        ("metrics", "overlap_dist_m"): 0.1,
    }
    for (stage, name), value in given.items():
        assert getattr(getattr(p, stage), name) == value, f"{stage}.{name}"
    defaults = params_to_dict(RegistrationParams())
    loaded = params_to_dict(p)
    for stage, values in defaults.items():
        if stage == "schema_version":
            continue
        for name, value in values.items():
            if (stage, name) not in given:
                assert json.dumps(loaded[stage][name]) == json.dumps(value), (
                    f"{stage}.{name}"
                )


def test_unknown_key_is_refused_by_name() -> None:
    with pytest.raises(InvalidInput, match=r"voxel_sise_m.*'preprocess'"):
        params_from_dict({"preprocess": {"voxel_sise_m": 0.02}})
    with pytest.raises(InvalidInput, match="prepocess"):
        params_from_dict({"prepocess": {"voxel_size_m": 0.02}})


def test_unknown_key_in_a_file_is_refused(tmp_path: Path) -> None:
    path = tmp_path / "p.json"
    path.write_text(json.dumps({"schema_version": 1, "fine": {"iters": 3}}))
    with pytest.raises(InvalidInput, match="iters"):
        load_params(path)


def test_newer_schema_is_refused() -> None:
    with pytest.raises(InvalidInput, match=r"schema_version 2 is newer"):
        params_from_dict({"schema_version": SCHEMA_VERSION + 1})
    with pytest.raises(InvalidInput, match="schema_version"):
        params_from_dict({"schema_version": "1"})


def test_bad_values_and_files_are_refused(tmp_path: Path) -> None:
    with pytest.raises(InvalidInput, match=r"fine\.method.*magic"):
        params_from_dict({"fine": {"method": "magic"}})
    with pytest.raises(
        InvalidInput,
        match=r"separate\.scales_k = \[2\] \(item 2\) is outside its range \[4, 100\]",
    ):
        params_from_dict({"separate": {"scales_k": [2]}})
    with pytest.raises(InvalidInput, match="table of values"):
        params_from_dict({"fine": 3})
    with pytest.raises(InvalidInput, match="not found"):
        load_params(tmp_path / "missing.json")
    bad = tmp_path / "bad.json"
    bad.write_text("{not json")
    with pytest.raises(InvalidInput, match="is not valid JSON"):
        load_params(bad)
    bad.write_text("[1, 2]")
    with pytest.raises(InvalidInput, match="JSON object"):
        load_params(bad)


@pytest.mark.parametrize(
    "bad",
    [
        {"keypoints": {"max_depth": 0}},
        {"fine": {"scales": 0}},
        {"match": {"levelled": "no"}},
    ],
)
def test_out_of_range_values_are_refused(bad) -> None:
    with pytest.raises(InvalidInput):
        params_from_dict(bad)


def test_every_preset_loads() -> None:
    files = sorted(PRESETS.glob("*.json"))
    assert files, f"no presets in {PRESETS}"
    presets = list_presets()
    assert sorted(presets.values()) == files
    for name, path in presets.items():
        p = load_preset(name)
        assert isinstance(p, RegistrationParams)
        assert _same(p, load_params(path))
        doc = json.loads(path.read_text(encoding="utf-8"))
        for stage, values in doc.items():
            if isinstance(values, dict):
                for key, value in values.items():
                    got = getattr(getattr(p, stage), key)
                    assert json.dumps(got) == json.dumps(value), (
                        f"{name}: {stage}.{key}"
                    )
    assert load_preset("Paper (Ren et al.)").fine.method == "lm_icp"
    assert load_preset("Leafless (winter)").separate.mode == "all_wood"
    assert load_preset("leafless") == load_preset("Leafless (winter)")  # its file
    with pytest.raises(InvalidInput, match="No preset named 'nope'; available: co"):
        load_preset("nope")


def _strict_json(text: str):
    """json.loads that refuses NaN / Infinity (as strict parsers do)."""

    def refuse(name: str):
        raise ValueError(f"not strict JSON: {name}")

    return json.loads(text, parse_constant=refuse)


@pytest.mark.parametrize(
    ("stage", "name"),
    [
        ("preprocess", "voxel_size_m"),
        ("fine", "max_corr_dist_m"),
        ("match", "edge_tolerance"),
        ("coarse", "tight_dist_m"),
    ],
)
@pytest.mark.parametrize("value", [float("nan"), float("inf"), float("-inf")])
def test_non_finite_values_are_refused_by_name(stage, name, value) -> None:
    # NaN compares false with everything, so a range check alone lets it through.
    with pytest.raises(InvalidInput, match=rf"{stage}\.{name}.*not a finite number"):
        params_from_dict({stage: {name: value}})


def test_non_finite_value_in_a_file_is_refused(tmp_path: Path) -> None:
    path = tmp_path / "p.json"
    path.write_text('{"preprocess": {"voxel_size_m": NaN}}')
    with pytest.raises(InvalidInput, match=r"preprocess\.voxel_size_m"):
        load_params(path)
    path.write_text('{"fine": {"max_corr_dist_m": Infinity}}')
    with pytest.raises(InvalidInput, match=r"fine\.max_corr_dist_m"):
        load_params(path)


def test_negative_seeds_are_refused_at_load_time() -> None:
    defaults = RegistrationParams()
    seeded = [
        f.name
        for f in dataclasses.fields(defaults)
        if "seed" in {g.name for g in dataclasses.fields(getattr(defaults, f.name))}
    ]
    assert {"coarse", "metrics", "trunk"} <= set(seeded)
    for stage in seeded:
        with pytest.raises(InvalidInput, match=rf"{stage}\.seed = -1 is negative"):
            params_from_dict({stage: {"seed": -1}})
        assert getattr(params_from_dict({stage: {"seed": 7}}), stage).seed == 7
        # The app's form shows seeds up to 2**31 - 1: a larger one is refused.
        with pytest.raises(InvalidInput, match=r"too large.*2147483647"):
            params_from_dict({stage: {"seed": 2**31}})
        assert getattr(params_from_dict({stage: {"seed": 2**31 - 1}}), stage).seed


@pytest.mark.parametrize(
    ("stage", "low", "high", "values"),
    [
        ("preprocess", "min_points", "max_points", (100000, 1000)),
        ("fine", "min_corr_dist_m", "max_corr_dist_m", (2.0, 0.01)),
        ("trunk", "slice_low_m", "slice_high_m", (3.0, 0.5)),
        ("trunk", "slice_low_m", "slice_high_m", (1.0, 1.0)),  # an empty slice
    ],
)
def test_contradictory_pairs_are_refused_naming_both(stage, low, high, values) -> None:
    with pytest.raises(InvalidInput) as exc:
        params_from_dict({stage: {low: values[0], high: values[1]}})
    assert f"{stage}.{low}" in str(exc.value)
    assert f"{stage}.{high}" in str(exc.value)


def test_ordered_pairs_may_touch() -> None:
    p = params_from_dict(
        {
            "preprocess": {"min_points": 5000, "max_points": 5000},
            "fine": {"min_corr_dist_m": 0.1, "max_corr_dist_m": 0.1},
        }
    )
    assert p.preprocess.min_points == p.preprocess.max_points == 5000


def test_schema_version_of_the_wrong_type_says_integer() -> None:
    for bad in ("1", 1.0, True, None, 0):
        with pytest.raises(InvalidInput, match="must be an integer") as exc:
            params_from_dict({"schema_version": bad})
        assert "newer" not in str(exc.value)


def test_a_folder_as_parameter_file_is_named_a_folder(tmp_path: Path) -> None:
    with pytest.raises(InvalidInput, match="is a folder") as exc:
        load_params(tmp_path)
    assert "not found" not in str(exc.value)
    with pytest.raises(InvalidInput, match="empty"):
        load_params("")


def test_nan_is_written_as_null_and_read_back(tmp_path: Path) -> None:
    path = tmp_path / "params.json"
    save_params(path, RegistrationParams())
    text = path.read_text(encoding="utf-8")
    assert "NaN" not in text
    doc = _strict_json(text)  # valid JSON for strict parsers
    assert doc["separate"]["intensity_threshold"] is None
    back = load_params(path)
    assert math.isnan(back.separate.intensity_threshold)
    assert _same(back, RegistrationParams())
    # Files written before (a bare NaN) keep loading, as does an explicit value.
    path.write_text('{"separate": {"intensity_threshold": NaN}}')
    assert math.isnan(load_params(path).separate.intensity_threshold)
    p = params_from_dict({"separate": {"intensity_threshold": 1200.0}})
    assert p.separate.intensity_threshold == 1200.0
    with pytest.raises(InvalidInput, match="intensity_threshold"):
        params_from_dict({"separate": {"intensity_threshold": float("inf")}})
    # Only "automatic" fields take null.
    with pytest.raises(InvalidInput, match=r"preprocess\.voxel_size_m"):
        params_from_dict({"preprocess": {"voxel_size_m": None}})
