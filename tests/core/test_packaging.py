"""The wheel carries everything an install outside the checkout needs."""

from __future__ import annotations

import subprocess
import sys
import zipfile
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
tomllib = pytest.importorskip("tomllib")


def _pyproject() -> dict:
    return tomllib.loads((ROOT / "pyproject.toml").read_text(encoding="utf-8"))


def test_package_list_matches_the_folders():
    listed = set(_pyproject()["tool"]["setuptools"]["packages"])
    found = {
        ".".join(init.parent.relative_to(ROOT).parts)
        for top in ("amrst", "amrst_gui")
        for init in (ROOT / top).rglob("__init__.py")
    }
    assert listed == found | {"amrst_resources"}


@pytest.mark.slow
def test_wheel_ships_presets_sample_and_icon(tmp_path):
    pytest.importorskip("setuptools")
    subprocess.run(
        [sys.executable, "-m", "pip", "wheel", "-q", "--no-deps",
         "--no-build-isolation", "-w", str(tmp_path), str(ROOT)],
        check=True, capture_output=True, timeout=240,
    )  # fmt: skip
    (wheel,) = tmp_path.glob("amrst_studio-*.whl")
    with zipfile.ZipFile(wheel) as zf:
        names = set(zf.namelist())
        zf.extractall(tmp_path / "site")
    for shipped in (
        "amrst_resources/presets/default.json",
        "amrst_resources/presets/paper.json",
        "amrst_resources/sample/target.ply",
        "amrst_resources/sample/source.ply",
        "amrst_resources/sample/truth.json",
        "amrst_resources/sample/LICENSE-itsme",
        "amrst_resources/icons/amrst.svg",
        "amrst/stages/match.py",
        "amrst_gui/panels/__init__.py",
    ):
        assert shipped in names
    # Installed from the wheel (first on the path), the engine finds its presets and
    # reads the sample from the installed package, not from this checkout.
    probe = (
        "import amrst.params as p, amrst.io as io;"
        "from amrst.resources import resource_path as r;"
        "print(r('sample'));"
        "print(sorted(p.list_presets()));"
        "print(len(io.read(r('sample', 'target.ply')).xyz))"
    )
    out = subprocess.run(
        [sys.executable, "-c", probe],
        check=True, capture_output=True, text=True, timeout=120,
        cwd=tmp_path, env={"PYTHONPATH": str(tmp_path / "site"), "PATH": "/usr/bin:/bin"},
    ).stdout.splitlines()  # fmt: skip
    assert Path(out[0]).is_relative_to(tmp_path / "site")
    assert "Default (any tree)" in out[1]
    assert "Paper (Ren et al.)" in out[1]
    assert int(out[2]) > 1000
