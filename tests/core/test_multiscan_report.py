"""``amrst register REF S2 S3 ... --report``: the report lists every link and scan."""

from __future__ import annotations

import json

import numpy as np
import pytest

import amrst
from amrst.cli import main
from amrst.multiscan.simulate import simulate_scans, write_scans
from amrst.results.report_multi import build_multi_html, how_reached
from amrst.types import Cloud


@pytest.fixture(scope="module")
def three_scans(tiny_tree):
    return simulate_scans(tiny_tree, 3, seed=0, res_deg=0.2)


def test_cli_report_lists_every_link_and_scan(tmp_path, three_scans, capsys):
    folder = write_scans(three_scans, tmp_path / "tree", "tiny", 0)
    scans = [str(folder / f"scan_{k}.ply") for k in range(3)]
    out = tmp_path / "out"
    code = main(
        [
            "register",
            *scans,
            *("--out", str(out), "--report", "--quiet"),
            *("--truth", str(folder / "truth.json")),
        ]
    )
    printed = capsys.readouterr().out
    assert code == 0, printed
    assert "report.html" in printed
    page = (out / "report.html").read_text(encoding="utf-8")
    doc = json.loads((out / "scans.json").read_text(encoding="utf-8"))
    assert "Registration of 3 scans onto" in page
    for link in doc["links"]:
        row = f"<td>{link['target']} ← {link['source']}</td><td>{link['status']}</td>"
        assert row + f"<td>{link['score']:.0%}</td>" in page
    for k, scan in enumerate(doc["scans"]):
        how = "reference" if k == 0 else "via " + " → ".join(map(str, scan["path"]))
        assert (
            f"<td>{scan['file']}</td><td>{scan['n_points']:,}</td><td>{how}</td>"
            in (page)
        )
        assert f"{scan['truth']['rotation_error_deg']:.3f}°" in page
    assert page.count("data:image/png;base64,") == 4  # the pair report's pictures
    assert ">Registered<" in page


def test_a_scan_not_reached_reads_so(three_scans):
    # a box of random points (no tree) verifies with neither scan: not reached
    rng = np.random.default_rng(0)
    box = Cloud(rng.uniform(-3, 3, (3000, 3)), np.zeros(3), {}, "box", {})
    result = amrst.register_scans([*three_scans.scans[:2], box])
    assert result.status == "needs review"
    page = build_multi_html(result, ["a.ply", "b.ply", "other.ply"], images={})
    assert how_reached(result, 2) == "NOT reached (no verified link)"
    assert "<td>other.ply</td>" in page
    assert "NOT reached (no verified link)" in page
    assert ">Needs review<" in page
    assert "<h2>Pictures</h2>" in page


def test_two_scans_by_spec_write_the_pair_report(tmp_path, three_scans, capsys):
    from _writers import write_e57

    plot = tmp_path / "plot.e57"
    write_e57(plot, three_scans.scans[:2])
    out = tmp_path / "out"
    code = main(
        ["register", f"{plot}#0", f"{plot}#1", "--out", str(out), "--report", "--quiet"]
    )
    assert code == 0, capsys.readouterr()
    page = (out / "report.html").read_text(encoding="utf-8")
    assert "Chosen candidate and alternatives" in page  # the pair report
