"""Optional dependencies: a missing one is named with its extra, in one line."""

from __future__ import annotations

import subprocess
import sys

import pytest

from amrst.extras import EXTRA_OF, MissingExtra, missing_extra, require


def test_require_returns_the_module() -> None:
    assert require("numpy", "testing").__name__ == "numpy"


def test_a_missing_module_names_its_extra(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setitem(EXTRA_OF, "pye57_not_here", "e57")
    with pytest.raises(MissingExtra, match=r"amrst-studio\[e57\]") as info:
        require("pye57_not_here", "reading E57 files")
    assert "\n" not in str(info.value)


def test_an_import_error_of_an_optional_module_becomes_one_line() -> None:
    exc = ModuleNotFoundError("No module named 'open3d'", name="open3d")
    found = missing_extra(exc, "amrst bench")
    assert found is not None
    assert str(found) == (
        "amrst bench needs open3d, which is not installed: "
        "pip install 'amrst-studio[baselines]'"
    )
    assert missing_extra(ModuleNotFoundError("x", name="numpyx"), "x") is None


def test_the_engine_imports_without_qt() -> None:
    """``import amrst`` and its CLI load no Qt, VTK, Open3D or Dask."""
    code = (
        "import sys, amrst, amrst.cli, amrst.pipeline; "
        "bad = [m for m in ('PySide6', 'pyvista', 'vtk', 'open3d', 'distributed') "
        "if m in sys.modules]; print(bad)"
    )
    out = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, check=True
    )
    assert out.stdout.strip() == "[]"
