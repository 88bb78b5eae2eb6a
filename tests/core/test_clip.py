"""``amrst clip`` / ``io.read_region``: one tree cut out of a plot file."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from amrst import cli, io
from amrst.clip import ClipParams, clip_tree
from amrst.errors import InvalidInput
from amrst.io import region
from amrst.types import Cloud

PEER = Path(__file__).resolve().parents[1] / "data" / "peer"


def _plot(n_trees: int = 4) -> Cloud:
    """Vertical 'stems' 3 m apart, 2,000 points each, georeferenced."""
    rng = np.random.default_rng(12)
    parts = []
    for i in range(n_trees):
        angle = rng.uniform(0, 2 * np.pi, 2000)
        r = rng.uniform(0, 0.3, 2000)
        parts.append(
            np.column_stack(
                [
                    3.0 * i + r * np.cos(angle),
                    r * np.sin(angle),
                    rng.uniform(0, 8, 2000),
                ]
            )
        )
    xyz = np.vstack(parts)
    return Cloud(
        xyz, [500000.0, 5000000.0, 200.0], {"intensity": rng.integers(0, 999, len(xyz))}
    )


def _inside(cloud: Cloud, x: float, y: float, r: float) -> np.ndarray:
    w = cloud.xyz + cloud.offset
    return (w[:, 0] - x) ** 2 + (w[:, 1] - y) ** 2 <= r**2


@pytest.mark.parametrize("ext", [".las", ".laz", ".ply"])
def test_clip_keeps_exactly_the_cylinder(tmp_path, ext, monkeypatch):
    monkeypatch.setattr(region, "CHUNK_POINTS", 1500)  # several chunks per file
    plot = _plot()
    io.write(tmp_path / f"plot{ext}", plot)
    full = io.read(tmp_path / f"plot{ext}")
    stem = (500006.0, 5000000.0)  # the third stem
    got = clip_tree(tmp_path / f"plot{ext}", ClipParams(stem_xy=stem, radius_m=1.0))
    want = full.select(_inside(full, *stem, 1.0))
    assert len(got.cloud) == len(want) == 2000
    np.testing.assert_allclose(
        np.sort(got.cloud.world_xyz, axis=0), np.sort(want.world_xyz, axis=0), atol=1e-6
    )
    assert got.cloud.attributes["intensity"].sum() == want.attributes["intensity"].sum()
    expected = "whole file" if ext == ".ply" else "streamed chunks"
    assert got.method == expected
    assert got.points_decoded == len(full)


def test_clip_heights(tmp_path):
    io.write(tmp_path / "plot.laz", _plot())
    got = io.read_region(
        tmp_path / "plot.laz", (500000.0, 5000000.0), 1.0, zmin=202.0, zmax=204.0
    )
    world = got.world_xyz
    assert 0 < len(got) < 2000
    assert world[:, 2].min() >= 202.0
    assert world[:, 2].max() <= 204.0


def test_copc_is_queried_not_read_whole():
    path = PEER / "laspy-simple.copc.laz"
    full = io.read(path)
    stem = (637500.0, 851500.0)
    got = io.read_region(path, stem, 300.0)
    assert got.meta["clip_method"] == "copc spatial query"
    assert got.meta["clip_points_decoded"] < len(full)
    assert len(got) == int(_inside(full, *stem, 300.0).sum()) > 0


def test_a_copc_index_that_finds_nothing_is_checked_against_the_points(
    tmp_path, monkeypatch: pytest.MonkeyPatch
):
    from amrst.io import region

    path = PEER / "pdal-autzen_clip_native.copc.laz"
    stem = (193919.0, 260584.0)
    assert len(io.read_region(path, stem, 5.0)) == 1
    # A sound index over a gap between points: said at once, the file not read whole.
    monkeypatch.setattr(region, "_stream", lambda *_: pytest.fail("read whole"))
    with pytest.raises(InvalidInput, match=r"no point lies within 0\.3 m"):
        io.read_region(path, stem, 0.3)
    monkeypatch.undo()
    broken = bytearray(path.read_bytes())
    broken[-200:] = bytes(b ^ 0x5A for b in broken[-200:])  # its hierarchy
    (tmp_path / "broken.copc.laz").write_bytes(bytes(broken))
    with pytest.raises(InvalidInput, match="corrupt"):  # not "no point lies"
        io.read_region(tmp_path / "broken.copc.laz", stem, 5.0)


def test_legacy_laz_is_clipped_too():
    got = io.read_region(
        PEER / "pdal-simple-laszip-compressor-version-1.2r0.laz", (637500, 851500), 300
    )
    assert len(got) == 21


def test_no_point_near_the_stem_gives_the_file_extent(tmp_path):
    io.write(tmp_path / "plot.laz", _plot())
    with pytest.raises(InvalidInput, match=r"no point lies within 1 m .* spans x 4999"):
        io.read_region(tmp_path / "plot.laz", (0.0, 0.0), 1.0)


@pytest.mark.parametrize(
    ("stem", "radius", "zmin", "zmax", "match"),
    [
        ((0.0, 0.0), 0.0, None, None, "radius must be a positive number"),
        ((0.0, 0.0), np.nan, None, None, "radius must be a positive number"),
        ((0.0, 0.0), 1e300, None, None, "radius must be a positive number"),
        ((0.0, np.nan), 1.0, None, None, "two numbers X Y within"),
        ((0.0, 1e12), 1.0, None, None, "two numbers X Y within"),
        ((0.0, 0.0), 1.0, np.inf, None, "zmin and zmax must be heights"),
        ((0.0, 0.0), 1.0, 5.0, 2.0, "zmin .* must be below zmax"),
    ],
)
def test_bad_cylinder_is_refused_before_reading(
    tmp_path, stem, radius, zmin, zmax, match
):
    with pytest.raises(InvalidInput, match=match):
        io.read_region(tmp_path / "missing.laz", stem, radius, zmin=zmin, zmax=zmax)


def test_cli_clips_one_tree_per_stem(tmp_path, capsys):
    io.write(tmp_path / "plot.laz", _plot())
    code = cli.main(
        [
            "clip", str(tmp_path / "plot.laz"),
            "--stem", "500000", "5000000", "--stem", "500003", "5000000",
            "--radius", "1", "--out", str(tmp_path / "tree.laz"),
        ]
    )  # fmt: skip
    assert code == 0
    assert len(io.read(tmp_path / "tree_1.laz")) == 2000
    assert len(io.read(tmp_path / "tree_2.laz")) == 2000
    assert "streamed chunks" in capsys.readouterr().err
    # A bad stem among them is refused before any tree is cut or said to be.
    code = cli.main(
        [
            "clip", str(tmp_path / "plot.laz"),
            "--stem", "500000", "5000000", "--stem", "nan", "0",
            "--radius", "1", "--out", str(tmp_path / "q.laz"),
        ]
    )  # fmt: skip
    assert code == 2
    err = capsys.readouterr().err
    assert err.startswith("amrst clip: The stem position must be two numbers")
    assert "q_1.laz" not in err
    assert not (tmp_path / "q_1.laz").exists()


def test_cli_refuses_an_unwritable_output_before_reading(tmp_path, capsys):
    code = cli.main(
        ["clip", str(tmp_path / "nope.laz"), "--stem", "0", "0",
         "--out", str(tmp_path / "no" / "tree.laz")]
    )  # fmt: skip
    assert code == 2
    assert "does not exist" in capsys.readouterr().err
    (tmp_path / "a.txt").write_text("a file, not a folder")
    (tmp_path / "dir.laz").mkdir()
    for out, says in (("a.txt/tree.laz", "a.txt is a file"), ("dir.laz", "a folder")):
        argv = ["clip", str(tmp_path / "nope.laz"), "--stem", "0", "0", "--out"]
        assert cli.main([*argv, str(tmp_path / out), "--overwrite"]) == 2
        assert says in capsys.readouterr().err


@pytest.mark.parametrize("ext", [".laz", ".pcd"])
def test_overview_is_an_even_thin_sample(tmp_path, ext, monkeypatch):
    monkeypatch.setattr(region, "CHUNK_POINTS", 1500)
    plot = _plot()
    io.write(tmp_path / f"plot{ext}", plot)
    view = io.read_overview(tmp_path / f"plot{ext}", max_points=1000)
    assert view.meta["overview_of"] == 8000
    assert len(view) == 1000  # every 8th point
    world = view.world_xyz
    for i in range(4):  # every stem is in it
        assert (np.abs(world[:, 0] - (500000.0 + 3.0 * i)) < 0.5).sum() > 200


def test_cli_never_writes_over_its_input_and_asks_before_replacing(tmp_path, capsys):
    plot = tmp_path / "plot.laz"
    io.write(plot, _plot())
    before = plot.read_bytes()
    stem = ["--stem", "500000", "5000000", "--radius", "1"]
    for extra in ([], ["--overwrite"]):
        assert cli.main(["clip", str(plot), *stem, "--out", str(plot), *extra]) == 2
        assert "is the file being clipped" in capsys.readouterr().err
    assert plot.read_bytes() == before
    tree = tmp_path / "tree.laz"
    tree.write_bytes(b"a tree clipped earlier")
    assert cli.main(["clip", str(plot), *stem, "--out", str(tree)]) == 2
    assert "add --overwrite" in capsys.readouterr().err
    assert tree.read_bytes() == b"a tree clipped earlier"
    assert cli.main(["clip", str(plot), *stem, "--out", str(tree), "--overwrite"]) == 0
    assert len(io.read(tree)) == 2000


def test_cli_writes_no_tree_when_one_stem_has_no_points(tmp_path, capsys):
    io.write(tmp_path / "plot.laz", _plot())
    stems = ["--stem", "500000", "5000000", "--stem", "0", "0", "--radius", "1"]
    out = ["--out", str(tmp_path / "tree.laz")]
    assert cli.main(["clip", str(tmp_path / "plot.laz"), *stems, *out]) == 2
    assert "no point lies within" in capsys.readouterr().err
    assert not list(tmp_path.glob("*tree*"))  # no tree, and no part of one
