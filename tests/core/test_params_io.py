"""Parameter files: round trips, the versioned v1 fixture, refusals, every preset."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import pytest

from amrst.errors import InvalidInput
from amrst.params_io import (
    SCHEMA_VERSION,
    list_presets,
    load_params,
    load_preset,
    params_from_dict,
    params_to_dict,
    save_params,
)
from amrst.pipeline import RegistrationParams

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
    with pytest.raises(InvalidInput, match="'separate'"):
        params_from_dict({"separate": {"scales_k": [2]}})
    with pytest.raises(InvalidInput, match="table of values"):
        params_from_dict({"fine": 3})
    with pytest.raises(InvalidInput, match="not found"):
        load_params(tmp_path / "missing.json")
    bad = tmp_path / "bad.json"
    bad.write_text("{not json")
    with pytest.raises(InvalidInput, match="must be JSON"):
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
    with pytest.raises(InvalidInput, match="No preset named"):
        load_preset("nope")
