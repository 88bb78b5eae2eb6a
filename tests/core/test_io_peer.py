"""Files written by other software (laspy's and PDAL's test data, tests/data/peer).

Each file has the outcome it must give (tests/data/peer/expected.json): the point
count its writer announced, or a refusal (exit 2, one line).
"""

from __future__ import annotations

import json
import logging
import os
import subprocess
import sys
from pathlib import Path

import pytest

from amrst import cli, io

PEER = Path(__file__).resolve().parents[1] / "data" / "peer"
EXPECTED = json.loads((PEER / "expected.json").read_text())
ROOT = Path(__file__).resolve().parents[2]


@pytest.mark.parametrize("name", sorted(EXPECTED))
def test_peer_file_gives_its_outcome(name, capsys, caplog):
    want = EXPECTED[name]
    with caplog.at_level(logging.WARNING):
        code = cli.main(["info", str(PEER / name)])
    out, err = capsys.readouterr()
    if "points" in want:
        assert code == 0, err
        assert f"points      {want['points']:,}" in out
        if "warning" in want:
            assert want["warning"] in caplog.text
        return
    assert code == cli.EXIT_INPUT
    assert len(err.strip().splitlines()) == 1
    assert want["refused"] in err


def test_copc_keeps_attributes_but_not_its_octree_vlrs(tmp_path):
    cloud = io.read(PEER / "laspy-simple.copc.laz")
    assert {"intensity", "classification"} <= cloud.attributes.keys()
    assert all(v[0] != "copc" for v in cloud.meta["las_vlrs"])
    io.write(tmp_path / "again.laz", cloud)  # the COPC VLRs would make this fail
    assert len(io.read(tmp_path / "again.laz")) == 1065


def _run_info(path: Path) -> subprocess.CompletedProcess[str]:
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    return subprocess.run(
        [sys.executable, "-m", "amrst.cli", "info", str(path)],
        capture_output=True,
        text=True,
        env=env,
        timeout=120,
    )


def test_legacy_laz_reads_without_decoder_noise():
    """LASzip 1.2 files read without a panic of the decoder (a Rust backtrace)."""
    proc = _run_info(PEER / "pdal-simple-laszip-compressor-version-1.2r0.laz")
    assert proc.returncode == 0
    assert "points      1,065" in proc.stdout
    assert proc.stderr == ""


def test_a_waveform_las_written_as_laz_reads_back_the_same(tmp_path):
    # Point format 4 carries wave packets: lazrs writes their LASzip item as version 2.
    import numpy as np

    cloud = io.read(PEER / "laspy-simple1_3.las")
    io.write(tmp_path / "again.laz", cloud)
    back = io.read(tmp_path / "again.laz")
    np.testing.assert_allclose(
        back.xyz + back.offset, cloud.xyz + cloud.offset, atol=1e-6
    )
    assert set(back.attributes) == set(cloud.attributes)
    for key, values in cloud.attributes.items():
        np.testing.assert_array_equal(back.attributes[key], values)
