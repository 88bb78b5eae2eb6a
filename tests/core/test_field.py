"""Field-like scans end to end, and every candidate source with a known answer.

``tests/data/field_pair``: a tree on a sloped ground with a neighbour and shrubs, cut
with a 3 m cylinder (MIT ITSMe trees, see its README). Without the scene stage the same
pair is not registered; with it, it is.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import pytest

import amrst
from amrst.io.cases import read_case
from amrst.params import RegistrationParams
from amrst.pipeline.sources import merge_same_solutions
from amrst.stages.candidates import CandidateList, Origin
from amrst.stages.global_match import GlobalMatchParams, match_globally
from amrst.stages.metrics import truth_errors
from amrst.stages.scene import GROUND
from amrst.types import apply_transform, invert_transform, make_transform

FIELD = Path(__file__).resolve().parents[1] / "data" / "field_pair"


@pytest.fixture(scope="module")
def field_case():
    return read_case(FIELD)


def _ok(result, T_true, source) -> bool:
    err = truth_errors(result.T_target_source, T_true, source.xyz)
    return err.rotation_error_deg < 1.0 and err.gt_rmse_m < 0.05


def test_field_pair_registers_with_the_scene_stage(field_case) -> None:
    r = amrst.register(field_case.target, field_case.source)
    assert r.coarse.verified
    assert _ok(r, field_case.T_target_source, field_case.source)
    for an, role in ((r.target, "target"), (r.source, "source")):
        assert an.scene is not None
        assert an.scene.has_ground
        # About as many ground points as the scene put in (after thinning).
        truth_ground = field_case.truth[f"labels_{role}"]["ground"]
        assert int(np.sum(an.scene.labels == GROUND)) == pytest.approx(
            truth_ground, rel=0.25
        )
        # The tree stages got the points above the ground only.
        assert len(an.xyz) < len(an.scene.labels)
    # Its height, DBH and crown are the tree's alone: no ground, neighbour or shrub.
    labels = [field_case.truth[f"labels_{role}"] for role in ("target", "source")]
    assert r.tree["target"].n_points == pytest.approx(labels[0]["tree"], rel=0.1)
    merged = r.tree["merged"].n_points
    assert 0.9 * sum(n["tree"] for n in labels) < merged
    assert merged < sum(n["tree"] + n["other"] for n in labels)


def test_only_the_feature_matcher_can_register(sample_pair) -> None:
    """Matching made impossible and the trunk search off: the feature matcher's pose
    is the verified winner; with it off too there is nothing to offer."""
    base = RegistrationParams()
    only_features = dataclasses.replace(
        base,
        match=dataclasses.replace(
            base.match, edge_tolerance=0.005, max_residual_m=0.001, retry_relaxed=False
        ),
        trunk=dataclasses.replace(base.trunk, mode="off"),
    )
    r = amrst.register(sample_pair.target, sample_pair.source, only_features)
    assert r.coarse.candidate.origin is Origin.FEATURES
    assert r.coarse.verified
    assert _ok(r, sample_pair.T_true, sample_pair.source)
    assert "features" in r.timings
    nothing = dataclasses.replace(
        only_features, global_match=GlobalMatchParams(mode="off")
    )
    with pytest.raises(amrst.RegistrationFailed):
        amrst.register(sample_pair.target, sample_pair.source, nothing)


def test_a_pose_found_twice_is_one_candidate_naming_both(sample_run) -> None:
    r = sample_run.result
    best = r.matches.candidates[0]
    assert best.origin is Origin.TETRAHEDRA
    twin = dataclasses.replace(
        best,
        id=999,
        origin=Origin.FEATURES,
        T_target_source=best.T_target_source @ make_transform(np.eye(3), [0.01, 0, 0]),
    )
    far = dataclasses.replace(
        best,
        id=1000,
        origin=Origin.TRUNK,
        T_target_source=make_transform(np.eye(3), [5.0, 0, 0]) @ best.T_target_source,
    )
    merged = merge_same_solutions(
        CandidateList((best, twin, far), 1), r.matches.source_centre
    )
    assert [c.id for c in merged.candidates] == [best.id, 1000]
    assert merged.candidates[0].origins == (Origin.TETRAHEDRA, Origin.FEATURES)
    assert merged.candidates[1].origins == (Origin.TRUNK,)
    assert [c.rank for c in merged.candidates] == [1, 2]


@pytest.mark.parametrize("matcher", ["kiss", "fpfh"])
def test_global_matchers_find_a_large_turn(tiny_tree, matcher: str) -> None:
    if matcher == "kiss":
        pytest.importorskip("kiss_matcher")
    c, s = np.cos(np.radians(120)), np.sin(np.radians(120))
    T_true = make_transform(
        np.array([[c, -s, 0], [s, c, 0], [0, 0, 1.0]]), [2.0, -1.0, 0.3]
    )
    target = tiny_tree.xyz[::3]  # 1,667 points keep RANSAC quick
    source = apply_transform(invert_transform(T_true), target)
    found = match_globally(target, source, GlobalMatchParams(matcher=matcher))
    assert found.found
    assert found.method == matcher
    err = truth_errors(found.T_target_source, T_true, source)
    assert err.rotation_error_deg < 3.0, err
    assert err.gt_rmse_m < 0.15, err


def test_register_command_on_the_field_pair(tmp_path, capsys) -> None:
    """Exit 0 and the sources named in transform.json; with the scene stage off the
    same pair exits 3 ("verified": false), never a silent wrong answer."""
    import json

    from amrst.cli import main

    args = [str(FIELD / "target.ply"), str(FIELD / "source.ply"), "--quiet"]
    assert main(["register", *args, "--out", str(tmp_path / "on")]) == 0
    # A --stem where no stem stands is said, with where the tree measured stands.
    capsys.readouterr()
    off_stem = ["--stem", "5.85", "-1.6", "--out", str(tmp_path / "stem")]
    assert main(["register", *args, *off_stem]) == 0
    err = capsys.readouterr().err
    assert "no stem within 1 m of --stem 5.85 -1.6: the tree measured stands at" in err
    on_stem = ["--stem", "5.85", "-0.18", "--out", str(tmp_path / "stem2")]
    assert main(["register", *args, *on_stem]) == 0
    assert "no stem" not in capsys.readouterr().err
    record = json.loads((tmp_path / "on" / "transform.json").read_text())
    assert record["verified"] is True
    assert record["coarse_candidate"]["found_by"][0] == "tetrahedra"
    params = tmp_path / "off.json"
    params.write_text(
        json.dumps({"scene": {"mode": "off"}, "global_match": {"mode": "off"}})
    )
    off = ["register", *args, "--out", str(tmp_path / "off"), "--params", str(params)]
    assert main(off) == 3
    record = json.loads((tmp_path / "off" / "transform.json").read_text())
    assert record["verified"] is False
    # ... and it was indeed wrong: the ground confuses the tree stages.
    case = read_case(FIELD)
    err = truth_errors(
        np.array(record["T_target_source"]), case.T_target_source, case.source.xyz
    )
    assert err.rotation_error_deg > 1.0 or err.gt_rmse_m > 0.05
