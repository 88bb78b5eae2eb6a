"""Fixtures shared by the engine tests: the bundled sample pair, the tiny tree, and one
registration of the sample pair per session (it takes a few seconds).

``tests/gui/conftest.py`` defines its own ``sample_pair`` (paths only); inside
``tests/gui`` that one wins, as pytest picks the nearest fixture.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path
from typing import Any, NamedTuple

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[1]


def run_json_script(
    script: str, *args: str, env: dict[str, str] | None = None, timeout: float = 300
) -> Any:
    """Run ``python -c script args`` in a fresh interpreter with the project on its
    path; return the JSON document on the last line it prints."""
    env = {**(os.environ if env is None else env), "PYTHONPATH": str(ROOT)}
    out = subprocess.run(
        [sys.executable, "-c", script, *args],
        env=env,
        capture_output=True,
        text=True,
        check=True,
        timeout=timeout,
    )
    return json.loads(out.stdout.strip().splitlines()[-1])


SAMPLE_DIR = ROOT / "resources" / "sample"
TINY_TREE = ROOT / "tests" / "data" / "tiny_tree" / "tree.ply"


class SamplePair(NamedTuple):
    """The bundled sample: two simulated scans of one tree and the exact truth."""

    target: object  # amrst.types.Cloud
    source: object  # amrst.types.Cloud
    T_true: np.ndarray  # (4, 4) T_target_source
    target_path: Path
    source_path: Path
    truth_path: Path


class SampleRun(NamedTuple):
    """One default registration of the sample pair, with the progress it reported."""

    result: object  # amrst.RegistrationResult
    progress: list  # [(fraction, message), ...] in call order


@pytest.fixture(scope="session")
def sample_pair() -> SamplePair:
    """resources/sample/{target,source}.ply read with amrst.io, and truth.json."""
    from amrst import io

    paths = [SAMPLE_DIR / n for n in ("target.ply", "source.ply", "truth.json")]
    missing = [p.name for p in paths if not p.is_file()]
    assert not missing, f"bundled sample incomplete in {SAMPLE_DIR}: missing {missing}"
    truth = json.loads(paths[2].read_text(encoding="utf-8"))
    T_true = np.asarray(truth["T_target_source"], dtype=float)
    assert T_true.shape == (4, 4)
    return SamplePair(io.read(paths[0]), io.read(paths[1]), T_true, *paths)


@pytest.fixture(scope="session")
def tiny_tree():
    """tests/data/tiny_tree/tree.ply: 5,000 points of a real (simulated-scan) tree."""
    from amrst import io

    assert TINY_TREE.is_file(), f"missing test data {TINY_TREE}"
    return io.read(TINY_TREE)


@pytest.fixture(scope="session")
def tiny_tree_path() -> Path:
    """The path of tests/data/tiny_tree/tree.ply (for a script in a fresh process)."""
    assert TINY_TREE.is_file(), f"missing test data {TINY_TREE}"
    return TINY_TREE


@pytest.fixture(scope="session")
def json_script() -> Any:
    """:func:`run_json_script`: a script in a fresh interpreter, its last JSON line."""
    return run_json_script


@pytest.fixture(scope="session")
def sample_run(sample_pair: SamplePair) -> SampleRun:
    """amrst.register on the sample pair with default parameters, run once."""
    import amrst
    from amrst.progress import EventReporter

    progress: list = []
    reporter = EventReporter(lambda f, m: progress.append((f, m)))
    result = amrst.register(sample_pair.target, sample_pair.source, reporter=reporter)
    return SampleRun(result, progress)
