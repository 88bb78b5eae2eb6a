"""A campaign's words and decisions: one vocabulary in every file, decisions undone.

Trees are run with :func:`amrst.campaign.run.run_tree` in this process (the task a
Dask worker runs), so the files are those ``amrst batch`` writes.
"""

from __future__ import annotations

import csv
import json
import os
import shutil

import numpy as np
import pytest

from amrst import io
from amrst.campaign import init_campaign, load_campaign
from amrst.campaign.batch import pending_trees
from amrst.campaign.review import (
    ACCEPTED,
    CLEAR,
    acceptance_warning,
    decide,
    decision_of,
    export_accepted,
    review_state,
)
from amrst.campaign.run import run_tree
from amrst.campaign.stored import read_stored_tree
from amrst.campaign.table import tree_row
from amrst.cli import main
from amrst.errors import InvalidInput
from amrst.review.verdict import STATUSES
from amrst.types import Cloud

STATES = {*STATUSES, "accepted", "rejected"}


@pytest.fixture(scope="module")
def campaign_dir(tmp_path_factory, sample_pair):
    """T01: the sample pair (registered); T02: a tree against a box of noise (failed)."""
    root = tmp_path_factory.mktemp("campaign")
    (root / "T01").mkdir()
    for name in ("target.ply", "source.ply", "truth.json"):
        shutil.copy(sample_pair.target_path.parent / name, root / "T01" / name)
    (root / "T02").mkdir()
    shutil.copy(sample_pair.target_path, root / "T02" / "target.ply")
    rng = np.random.default_rng(0)
    box = Cloud(rng.uniform(-3, 3, (3000, 3)), np.zeros(3), {}, "box", {})
    io.write(root / "T02" / "source.ply", box)
    campaign, _ = init_campaign(root)
    todo, _, params = pending_trees(campaign)
    for entry, stamp in todo:
        row = run_tree(str(root), entry, params, stamp, threads=1)
        assert row["ok"], row
    return root


def _table(root):
    with open(root / "campaign.csv", newline="") as f:
        return {r["tree_id"]: r for r in csv.DictReader(f)}


def test_every_file_says_the_same_state(campaign_dir):
    campaign = load_campaign(campaign_dir)
    states = {}
    for tree in ("T01", "T02"):
        out = campaign_dir / "results" / tree
        scans = json.loads((out / "scans.json").read_text())
        metrics = json.loads((out / "metrics.json").read_text())
        stamp = json.loads((out / "stamp.json").read_text())
        assert scans["status"] == metrics["verdict"]["status"] == stamp["status"]
        assert {d["status"] for d in scans["links"]} == {scans["status"]}
        assert "verdict" not in scans
        assert "verdict" not in stamp
        assert tree_row(campaign, campaign.tree(tree))["status"] == scans["status"]
        assert read_stored_tree(campaign, tree).status == scans["status"]
        page = (out / "report.html").read_text(encoding="utf-8")
        assert f">{scans['status'].capitalize()}<" in page
        assert "report.html" in stamp["files"]
        states[tree] = scans["status"]
    assert states == {"T01": "registered", "T02": "failed"}


def test_accepting_a_failed_tree_needs_a_confirmation_and_can_be_undone(
    campaign_dir, capsys
):
    campaign = load_campaign(campaign_dir)
    assert acceptance_warning(campaign, "T01") == ""
    warning = acceptance_warning(campaign, "T02")
    assert warning.startswith("Tree T02 failed")
    with pytest.raises(InvalidInput, match="--confirm-unregistered") as info:
        decide(campaign, ["T01", "T02"], ACCEPTED)
    assert "\n" not in str(info.value)
    assert decision_of(campaign, "T01") == ""  # nothing written when one is refused
    # the command line refuses in one line and takes the flag
    assert main(["campaign", "decide", str(campaign_dir), "T02", "accepted"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1
    assert warning in err
    code = main(
        [
            "campaign",
            "decide",
            str(campaign_dir),
            "T01",
            "T02",
            "accepted",
            "--confirm-unregistered",
        ]
    )
    assert code == 0
    assert "T02: accepted" in capsys.readouterr().out
    assert review_state(campaign, "T02", "failed") == "accepted"
    rows = _table(campaign_dir)
    assert (rows["T02"]["status"], rows["T02"]["decision"]) == ("failed", "accepted")
    review = json.loads((campaign_dir / "results" / "T02" / "review.json").read_text())
    assert review["registration_status"] == "failed"
    # export says where it wrote, then the decision is cleared: back to the batch state
    assert main(["campaign", "export", str(campaign_dir)]) == 0
    printed = capsys.readouterr().out
    for tree in ("T01", "T02"):
        path = campaign_dir / "results" / tree / "merged.ply"
        assert f"wrote {path}" in printed
        assert path.is_file()
    assert main(["campaign", "decide", str(campaign_dir), "T02", "clear"]) == 0
    assert review_state(campaign, "T02", "failed") == "failed"
    assert _table(campaign_dir)["T02"]["decision"] == ""
    assert [p.parent.name for p in export_accepted(campaign)[0]] == ["T01"]
    decide(campaign, ["T01"], CLEAR)
    assert decision_of(campaign, "T01") == ""
    review = json.loads((campaign_dir / "results" / "T01" / "review.json").read_text())
    assert review["exported"] == "merged.ply"  # the export is still on record
    assert export_accepted(campaign) == ([], {})
    # the status command says both: the state and the decision
    decide(campaign, ["T01"], "rejected")
    capsys.readouterr()
    assert main(["campaign", "status", str(campaign_dir)]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert lines[0].split()[:3] == ["T01", "registered", "rejected"]
    assert lines[1].split()[:2] == ["T02", "failed"]
    words = {w for line in lines[:2] for w in line.split()[1:3]} - {"confidence"}
    assert words <= STATES


def test_unknown_decision_and_tree_are_one_line(campaign_dir):
    campaign = load_campaign(campaign_dir)
    with pytest.raises(InvalidInput, match="choose accepted, rejected or clear"):
        decide(campaign, ["T01"], "verified")
    with pytest.raises(InvalidInput, match="T09"):
        decide(campaign, ["T09"], CLEAR)


def test_files_of_older_versions_read_in_the_new_words(campaign_dir, tmp_path):
    """scans.json once said verdict verified/unverified/partial/failed."""
    shutil.copytree(campaign_dir, tmp_path / "c")
    root = tmp_path / "c"
    for tree, old in (("T01", "verified"), ("T02", "unverified")):
        path = root / "results" / tree / "scans.json"
        doc = json.loads(path.read_text())
        doc["verdict"] = old
        del doc["status"]
        for link in doc["links"]:
            link["verdict"] = old
            del link["status"], link["verified"]
        path.write_text(json.dumps(doc))
    # an older pair's metrics.json: the verdict is taken from there when present
    (root / "results" / "T02" / "metrics.json").unlink()
    campaign = load_campaign(root)
    t01, t02 = (read_stored_tree(campaign, t) for t in ("T01", "T02"))
    assert (t01.status, t01.links[0].status, t01.links[0].verified) == (
        "registered",
        "registered",
        True,
    )
    assert (t02.status, t02.links[0].status, t02.links[0].verified) == (
        "failed",
        "failed",
        False,
    )
    assert tree_row(campaign, campaign.tree("T02"))["status"] == "failed"
    # a partly placed tree of several scans needs review
    path = root / "results" / "T01" / "scans.json"
    doc = json.loads(path.read_text())
    doc.update(verdict="partial", n_scans=3)
    path.write_text(json.dumps(doc))
    assert tree_row(campaign, campaign.tree("T01"))["status"] == "needs review"


def _manifest_scans(root, tree: str, scans: list[str]) -> None:
    """Give ``tree`` these scans in campaign.toml, as a technician edits it."""
    text = (root / "campaign.toml").read_text()
    start = text.index(f'id = "{tree}"')
    head, rest = text[:start], text[start:]
    line = next(x for x in rest.splitlines() if x.startswith("scans ="))
    (root / "campaign.toml").write_text(
        head + rest.replace(line, f"scans = {json.dumps(scans)}", 1)
    )


def test_a_result_no_longer_of_the_listed_scans_is_not_exported(campaign_dir, tmp_path):
    shutil.copytree(campaign_dir, tmp_path / "c")
    root = tmp_path / "c"
    campaign = load_campaign(root)
    decide(campaign, ["T01"], ACCEPTED)
    (root / "results" / "T01" / "merged.ply").unlink(missing_ok=True)
    # The scans swapped in the manifest: the stored poses are of the other order.
    listed = list(campaign.tree("T01").scans)
    _manifest_scans(root, "T01", listed[::-1])
    written, errors = export_accepted(load_campaign(root))
    assert written == []
    assert "out of date: its list of scans or its reference changed" in errors["T01"]
    # The table says so too, and shows no decision for a result of other scans.
    swapped = load_campaign(root)
    row = tree_row(swapped, swapped.tree("T01"))
    assert row["status"] == "out of date"
    assert review_state(swapped, "T01", row["status"]) == "out of date"
    with pytest.raises(InvalidInput, match="run it again first"):
        decide(swapped, ["T01"], "rejected")
    assert read_stored_tree(swapped, "T01") is None  # its poses are of other scans
    assert not (root / "results" / "T01" / "merged.ply").exists()
    # The same scans, one file's content changed.
    _manifest_scans(root, "T01", listed)
    assert export_accepted(load_campaign(root))[1] == {}
    source = root / "T01" / "source.ply"
    os.utime(source)  # a new time, the same content: still its result
    assert tree_row(campaign, campaign.tree("T01"))["status"] != "out of date"
    cloud = io.read(source)
    io.write(source, cloud.select(np.arange(0, len(cloud), 2)))
    errors = export_accepted(load_campaign(root))[1]
    assert "its scans' contents changed" in errors["T01"]
    # The table (amrst campaign status, the Campaign dock) says so before the export.
    assert tree_row(campaign, campaign.tree("T01"))["status"] == "out of date"


def test_a_run_cancelled_midway_leaves_no_result_to_decide_on(campaign_dir, tmp_path):
    shutil.copytree(campaign_dir, tmp_path / "c")
    root = tmp_path / "c"
    campaign = load_campaign(root)
    (root / "results" / "T01" / "stamp.json").unlink()  # as run_tree starts
    assert acceptance_warning(campaign, "T01") == ""
    with pytest.raises(InvalidInput, match="no result to accept"):
        decide(campaign, ["T01"], ACCEPTED)
    assert decision_of(campaign, "T01") == ""


def test_a_decision_holds_for_the_result_it_was_made_on(campaign_dir, tmp_path):
    shutil.copytree(campaign_dir, tmp_path / "c")
    root = tmp_path / "c"
    campaign = load_campaign(root)
    decide(campaign, ["T02"], ACCEPTED, confirm_unregistered=True)
    assert decision_of(campaign, "T02") == ACCEPTED
    # Run again (forced): a new result, which nobody has looked at yet.
    todo, _, params = pending_trees(campaign, force=True)
    entry, stamp = next((e, s) for e, s in todo if e.id == "T02")
    assert run_tree(str(root), entry, params, stamp, threads=1)["ok"]
    assert decision_of(campaign, "T02") == ""
    assert export_accepted(campaign) == ([], {})


def test_a_broken_scans_json_is_one_line_at_export(campaign_dir, tmp_path):
    shutil.copytree(campaign_dir, tmp_path / "c")
    root = tmp_path / "c"
    campaign = load_campaign(root)
    decide(campaign, ["T01"], ACCEPTED)
    path = root / "results" / "T01" / "scans.json"
    doc = json.loads(path.read_text())
    doc["scans"][1]["T_reference_scan"] = np.eye(3).tolist()
    path.write_text(json.dumps(doc))
    errors = export_accepted(campaign)[1]
    assert "scans.json cannot be read" in errors["T01"]
    assert "\n" not in errors["T01"]


def test_scans_outside_the_campaign_folder_are_stamped_by_their_path(
    campaign_dir, tmp_path
):
    from amrst.campaign.run import tree_inputs

    shutil.copytree(campaign_dir, tmp_path / "c")
    root = tmp_path / "c"
    shutil.copytree(root / "T01", tmp_path / "elsewhere")
    outside = [str(tmp_path / "elsewhere" / n) for n in ("target.ply", "source.ply")]
    _manifest_scans(root, "T01", outside)
    text = (root / "campaign.toml").read_text()
    text = text.replace('reference = "T01/target.ply"', "reference = 0", 1)
    (root / "campaign.toml").write_text(text)
    campaign = load_campaign(root)
    files = tree_inputs(root.resolve(), campaign.tree("T01"))["files"]
    assert sorted(files) == sorted(outside)
    todo, done, _ = pending_trees(campaign)
    assert [e.id for e, _ in todo] == ["T01"]  # other files: run again
    assert done == ["T02"]
