"""Campaigns: manifest, init from a folder layout, the results table."""

from __future__ import annotations

import os
import shutil

import numpy as np
import pytest
from _writers import write_e57

from amrst.campaign import init_campaign, load_campaign
from amrst.campaign.manifest import MANIFEST, tree_tables
from amrst.campaign.table import COLUMNS
from amrst.cli import main
from amrst.errors import InvalidInput
from amrst.types import Cloud


def _layout(root, sample_pair):
    """T01: the sample pair (target/source); T02: one E57 with 3 scans; lonely: 1 scan."""
    (root / "T01").mkdir(parents=True)
    for name in ("target.ply", "source.ply", "truth.json"):
        shutil.copy(sample_pair.target_path.parent / name, root / "T01" / name)
    (root / "T02").mkdir()
    rng = np.random.default_rng(0)
    write_e57(
        root / "T02" / "plot.e57", [Cloud(rng.normal(size=(50, 3))) for _ in range(3)]
    )
    (root / "lonely").mkdir()
    shutil.copy(sample_pair.target_path, root / "lonely" / "only.ply")
    shutil.copy(sample_pair.target_path, root / "loose.ply")


def test_init_pairs_folders_and_says_what_it_could_not(tmp_path, sample_pair):
    _layout(tmp_path, sample_pair)
    campaign, skipped = init_campaign(tmp_path)
    assert [t.id for t in campaign.trees] == ["T01", "T02"]
    t01, t02 = campaign.trees
    assert t01.scans == ("T01/source.ply", "T01/target.ply")
    assert t01.scans[t01.reference] == "T01/target.ply"  # target.* is the reference
    assert t01.truth == "T01/truth.json"
    assert t02.scans == ("T02/plot.e57#0", "T02/plot.e57#1", "T02/plot.e57#2")
    assert t02.reference == 0
    assert any("lonely" in s and "only one scan" in s for s in skipped)
    assert any("loose.ply" in s for s in skipped)


def test_hand_edits_survive_a_second_init(tmp_path, sample_pair):
    _layout(tmp_path, sample_pair)
    init_campaign(tmp_path)
    text = (tmp_path / MANIFEST).read_text()
    text = text.replace(
        'reference = "T02/plot.e57#0"',
        "reference = 2  # the setup on the ridge\nstem = [1.5, -2.0]",
    )
    (tmp_path / MANIFEST).write_text(text)
    (tmp_path / "T03").mkdir()
    for name in ("a.ply", "b.ply"):
        shutil.copy(sample_pair.target_path, tmp_path / "T03" / name)
    campaign, _ = init_campaign(tmp_path)
    t02 = campaign.tree("T02")
    assert t02.reference == 2
    assert t02.stem == (1.5, -2.0)
    assert campaign.tree("T03").scans == ("T03/a.ply", "T03/b.ply")
    assert (
        load_campaign(tmp_path).trees == campaign.trees
    )  # what was written reads back
    # The file keeps its text, comments too; the new tree's table is added at its end.
    after = (tmp_path / MANIFEST).read_text()
    assert after.startswith(text)
    assert after[len(text) :] == tree_tables([campaign.tree("T03")])
    # An id changed by hand is the same tree (its scans): not added again.
    (tmp_path / MANIFEST).write_text(after.replace('id = "T03"', 'id = "ridge"'))
    again, _ = init_campaign(tmp_path)
    assert [t.id for t in again.trees].count("ridge") == 1
    assert "T03" not in [t.id for t in again.trees]


def test_csv_manifest(tmp_path):
    (tmp_path / "manifest.csv").write_text(
        "id,scans,reference,stem_x,stem_y,truth\nA1,a.ply;b.ply;c.ply,b.ply,10.5,20.25,\n"
    )
    (tree,) = load_campaign(tmp_path).trees
    assert tree.scans == ("a.ply", "b.ply", "c.ply")
    assert tree.reference == 1
    assert tree.stem == (10.5, 20.25)


@pytest.mark.parametrize(
    ("text", "message"),
    [
        ("[[tree]\nid=1", "not valid TOML"),
        ('[[tree]]\nid = "a b"\nscans = ["x.ply", "y.ply"]', "tree id"),
        ('[[tree]]\nid = "A"\nscans = ["x.ply"]', "at least 2"),
        (
            '[[tree]]\nid = "A"\nscans = ["x.ply", "y.ply"]\nreference = "z.ply"',
            "not one of its scans",
        ),
        (
            '[[tree]]\nid = "A"\nscans = ["x.ply", "y.ply"]\n[[tree]]\nid = "A"\nscans = ["x.ply", "y.ply"]',
            "unique",
        ),
        ('[[tree]]\nid = "A"\nscans = ["x.ply", "y.ply"]\nstem = [1]', "stem"),
        ('[[tree]]\nid = "A"\nscans = ["x.ply", "y.ply"]\nstem = [nan, 2]', "stem"),
        ('[[tree]]\nid = "A"\nscans = ["x.ply", "y.ply"]\nstem = [true, 2]', "stem"),
        ('[[tree]]\nid = "A"\nscans = ["x.ply", "y.ply"]\nstem = [1e30, 1e30]', "stem"),
        (
            '[[tree]]\nid = "A"\nscans = ["x.ply", "y.ply"]\nstem = [9223372036854775807, 0]',
            "stem",
        ),
        ('[[tree]]\nid = "A"\nscans = ["x.ply", "./x.ply"]', "listed twice"),
        ('[[tree]]\nid = "A"\nscans = ["x.ply", "y.ply"]\nreferense = 1', "referense"),
        ('campaign = 5\n[[tree]]\nid = "A"\nscans = ["x.ply", "y.ply"]', "table"),
        ('[campaign]\nnmae = "x"\n[[tree]]\nid = "A"\nscans = ["x", "y"]', "nmae"),
        ("tree = [5]", "must be a \\[\\[tree\\]\\] table"),
        ('[campaign]\nname = "x"', "lists no trees"),
        ("", "lists no trees"),
        (
            '[[tree]]\nid = "A"\nscans = ["x.ply", "y.ply\\u0000"]',
            "tree A\\): 'scans' holds a NUL",
        ),
        (
            '[[tree]]\nid = "A"\nscans = ["x.ply", "y.ply"]\ntruth = "t\\u0000.json"',
            "tree A\\): 'truth' holds a NUL",
        ),
        (
            '[campaign]\nparams = "p\\u0000.json"\n[[tree]]\nid = "A"\nscans = ["x", "y"]',
            "\\[campaign\\]: 'params' holds a NUL",
        ),
        (
            '[campaign]\npreset = "Conifer"\nparams = "p.json"\n'
            '[[tree]]\nid = "A"\nscans = ["x", "y"]',
            "a preset or a params file, not both",
        ),
    ],
)
def test_bad_manifest_one_line(tmp_path, text, message):
    (tmp_path / MANIFEST).write_text(text)
    with pytest.raises(InvalidInput, match=message) as info:
        load_campaign(tmp_path)
    assert "\n" not in str(info.value)


@pytest.mark.parametrize(
    ("data", "message"),
    [
        (b"\x00\x01\xff\xfe", "not UTF-8"),
        (b"id;scans\nA;x.ply y.ply\n", "comma-separated"),
        (b"id,scans,notes\nA,x.ply;y.ply,z\n", "notes"),
        (b"id,scans,stem_x\nA,x.ply;y.ply,1\n", "stem"),
        (b"id,scans,stem_x,stem_y\nA,x.ply;y.ply,1e30,0\n", "within 1e\\+09 m"),
        (b"id,scans\nA,x.ply;y.ply\x00\n", "tree A\\): 'scans' holds a NUL"),
    ],
)
def test_bad_csv_manifest_one_line(tmp_path, data, message):
    (tmp_path / "manifest.csv").write_bytes(data)
    with pytest.raises(InvalidInput, match=message) as info:
        load_campaign(tmp_path)
    assert "\n" not in str(info.value)


def test_a_csv_manifest_saved_by_a_spreadsheet_reads(tmp_path):
    (tmp_path / "manifest.csv").write_bytes(b"\xef\xbb\xbfid,scans\nA,x.ply;y.ply\n")
    assert load_campaign(tmp_path).tree("A").scans == ("x.ply", "y.ply")


def test_a_campaign_toml_not_in_utf8_is_one_line(tmp_path):
    # An editor saving in Latin-1 writes "café" as caf\xe9.
    (tmp_path / MANIFEST).write_bytes(
        b'[[tree]]\nid = "A"\nscans = ["x.ply", "y.ply"]\n# caf\xe9\n'
    )
    with pytest.raises(InvalidInput, match="not UTF-8 text; save it as UTF-8") as info:
        load_campaign(tmp_path)
    assert MANIFEST in str(info.value)
    assert "\n" not in str(info.value)


def test_a_campaign_toml_with_a_byte_order_mark_reads(tmp_path):
    (tmp_path / MANIFEST).write_bytes(
        b'\xef\xbb\xbf[[tree]]\r\nid = "A"\r\nscans = ["x.ply", "y.ply"]\r\n'
    )
    assert load_campaign(tmp_path).tree("A").scans == ("x.ply", "y.ply")


@pytest.mark.parametrize("bad", ["T01/\udcffa.ply", "T\udce901/a.ply"])
def test_init_refuses_a_scan_name_that_is_not_utf8(tmp_path, bad):
    # A name in bytes that are not UTF-8, as a Latin-1 "café" is: Python holds each
    # such byte as a surrogate, which campaign.toml (UTF-8) cannot hold.
    for rel in ("T01/b.ply", bad):
        try:
            (tmp_path / rel).parent.mkdir(exist_ok=True)
            (tmp_path / rel).write_text("ply\n")
        except (OSError, UnicodeEncodeError):
            pytest.skip("this file system takes UTF-8 names only")
    (tmp_path / "T02").mkdir()
    for name in ("a.ply", "b.ply"):
        (tmp_path / "T02" / name).write_text("ply\n")
    with pytest.raises(InvalidInput, match="not UTF-8 text") as info:
        init_campaign(tmp_path)
    shown = os.fsencode(bad).decode("utf-8", "backslashreplace")
    assert shown in str(info.value)  # e.g. T01/\xffa.ply
    assert "rename it" in str(info.value)
    assert "\n" not in str(info.value)
    assert not (tmp_path / MANIFEST).exists()


def test_init_refuses_a_campaign_folder_name_that_is_not_utf8(tmp_path):
    root = tmp_path / "plot\udce9"  # its name would be the campaign's name
    try:
        (root / "T01").mkdir(parents=True)
    except (OSError, UnicodeEncodeError):
        pytest.skip("this file system takes UTF-8 names only")
    for name in ("a.ply", "b.ply"):
        (root / "T01" / name).write_text("ply\n")
    with pytest.raises(InvalidInput, match=r"plot\\xe9: this name is not UTF-8"):
        init_campaign(root)
    assert not (root / MANIFEST).exists()


def test_init_on_a_folder_without_trees_writes_nothing(tmp_path):
    (tmp_path / "lonely").mkdir()
    with pytest.raises(InvalidInput, match="No tree found") as info:
        init_campaign(tmp_path)
    assert "no scan file" in str(info.value)
    assert not (tmp_path / MANIFEST).exists()


def test_cli_init_and_status(tmp_path, sample_pair, capsys):
    _layout(tmp_path, sample_pair)
    assert main(["campaign", "init", str(tmp_path)]) == 0
    out = capsys.readouterr().out
    assert "T02: 3 scans" in out
    assert "not paired: lonely" in out
    assert main(["campaign", "status", str(tmp_path)]) == 0
    assert "2 not run" in capsys.readouterr().out
    assert main(["campaign", "status", str(tmp_path / "nothing")]) == 2


def test_table_columns_3dfin_names():
    for name in (
        "TH",
        "DBH",
        "X",
        "Y",
        "status",
        "decision",
        "confidence",
        "NN_RMSE_m",
        "overlap",
    ):
        assert name in COLUMNS


def test_the_campaign_s_own_tables_are_not_taken_for_loose_scans(tmp_path, sample_pair):
    from amrst.campaign.table import write_table

    _layout(tmp_path, sample_pair)
    campaign, _ = init_campaign(tmp_path)
    write_table(campaign)  # campaign.csv, as a batch leaves it
    (tmp_path / "manifest.csv").write_text("id,scans\n")
    _, skipped = init_campaign(tmp_path)
    (loose,) = [why for why in skipped if "directly in" in why]
    assert loose.startswith("1 scan file(s)")  # loose.ply only
    assert "campaign.csv" not in loose
    assert "manifest.csv" not in loose


@pytest.mark.parametrize(
    "command",
    [["campaign", "init"], ["campaign", "status"], ["batch", "--workers", "1"]],
)
def test_an_empty_campaign_folder_name_is_refused(
    tmp_path, monkeypatch, capsys, command
):
    # An empty name must not stand for the folder the command is run in.
    (tmp_path / "T01").mkdir()
    for name in ("a.ply", "b.ply"):
        (tmp_path / "T01" / name).write_text("ply\n")
    (tmp_path / MANIFEST).write_text(
        '[[tree]]\nid = "T01"\nscans = ["T01/a.ply", "T01/b.ply"]\n'
    )
    before = sorted(tmp_path.rglob("*"))
    monkeypatch.chdir(tmp_path)
    with pytest.raises(SystemExit) as exc:  # the command line refuses it first
        main([*command, ""])
    assert exc.value.code == 2
    err = capsys.readouterr().err
    assert "an empty argument was given" in err
    assert err.count("\n") == 1
    for api in (load_campaign, init_campaign):  # and so does the library
        with pytest.raises(InvalidInput, match="give the campaign folder"):
            api("")
    assert sorted(tmp_path.rglob("*")) == before


def test_init_writes_a_scan_name_with_a_line_break_as_valid_toml(tmp_path):
    (tmp_path / "T01").mkdir()
    for name in ("a.ply", "b\nc\t\x7f.ply"):
        try:
            (tmp_path / "T01" / name).write_text("ply\n")
        except OSError:
            pytest.skip("this file system refuses control characters in names")
    campaign, _ = init_campaign(tmp_path)
    assert campaign.tree("T01").scans == ("T01/a.ply", "T01/b\nc\t\x7f.ply")
