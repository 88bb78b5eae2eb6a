"""metrics.json's point counts against the clouds an export writes.

``n_points`` is a cloud's size; the sample a measurement used is
``n_points_measured``. The bundled sample is smaller than the measurement's sample,
so it is also registered densified (each point with 29 jittered copies, over 200,000
points a scan), where the measurement samples the clouds.
"""

from __future__ import annotations

import json
import subprocess
import sys
from typing import Any

import numpy as np
import pytest

from amrst import io
from amrst.sampling import MEASURE_MAX_POINTS
from amrst.types import Cloud

COPIES = 30  # the sample's ~7,000 points a scan, 30 times: over MEASURE_MAX_POINTS


def _densified(cloud: Cloud, seed: int) -> Cloud:
    jitter = np.random.default_rng(seed).normal(0, 0.002, (COPIES, *cloud.xyz.shape))
    return Cloud((cloud.xyz + jitter).reshape(-1, 3), cloud.offset)


def _register(tmp_path, target_path, source_path) -> dict[str, Any]:
    out = tmp_path / "out"
    proc = subprocess.run(
        [
            sys.executable,
            "-m",
            "amrst.cli",
            "register",
            str(target_path),
            str(source_path),
            "--out",
            str(out),
            "--write-clouds",
            "--quiet",
        ],
        capture_output=True,
        text=True,
        timeout=600,
        check=False,
    )
    assert proc.returncode == 0, proc.stderr
    metrics = json.loads((out / "metrics.json").read_text(encoding="utf-8"))
    return {
        "metrics": metrics,
        "target": len(io.read(target_path)),
        "source": len(io.read(out / "registered_source.ply")),
        "merged": len(io.read(out / "merged.ply")),
    }


@pytest.fixture(scope="module", params=["as bundled", "densified"])
def export(request, sample_pair, tmp_path_factory) -> dict[str, Any]:
    """The sample pair registered by ``amrst register --write-clouds``."""
    tmp = tmp_path_factory.mktemp("export_counts")
    if request.param == "as bundled":
        return _register(tmp, sample_pair.target_path, sample_pair.source_path)
    target, source = tmp / "target.ply", tmp / "source.ply"
    io.write(target, _densified(sample_pair.target, 0))
    io.write(source, _densified(sample_pair.source, 1))
    return _register(tmp, target, source)


def _counts(doc: Any, path: str = "") -> dict[str, int]:
    """Every ``n_points`` of a metrics document, by its dotted path."""
    found: dict[str, int] = {}
    if isinstance(doc, dict):
        for key, value in doc.items():
            where = f"{path}.{key}" if path else key
            if key == "n_points":
                found[where] = value
            else:
                found.update(_counts(value, where))
    elif isinstance(doc, list):
        for i, value in enumerate(doc):
            found.update(_counts(value, f"{path}[{i}]"))
    return found


def test_tree_counts_are_the_written_clouds_sizes(export):
    tree = export["metrics"]["tree"]
    for name in ("target", "source", "merged"):
        assert tree[name]["n_points"] == export[name], name
        measured = tree[name]["n_points_measured"]
        assert measured <= tree[name]["n_points"]
    if export["target"] > MEASURE_MAX_POINTS:  # the densified pair: sampled
        assert tree["target"]["n_points_measured"] == MEASURE_MAX_POINTS
        assert tree["merged"]["n_points_measured"] == 2 * MEASURE_MAX_POINTS


def test_every_n_points_is_a_clouds_size(export):
    sizes = {export["target"], export["source"], export["merged"]}
    counts = _counts(export["metrics"])
    assert len(counts) >= 3
    wrong = {where: n for where, n in counts.items() if n not in sizes}
    assert not wrong, wrong
