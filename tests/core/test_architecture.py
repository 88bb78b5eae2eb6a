"""The engine runs where Qt and pyvista cannot be imported."""

from __future__ import annotations

import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
BLOCKED = ("PySide6", "qtpy", "pyvista", "pyvistaqt", "superqt", "amrst_gui")

SCRIPT = textwrap.dedent(
    """
    import importlib.abc
    import sys

    BLOCKED = {blocked!r}

    class Block(importlib.abc.MetaPathFinder):
        def find_spec(self, name, path=None, target=None):
            if name.split(".")[0] in BLOCKED:
                raise ImportError(f"{{name}} is blocked in the Qt-free engine test")
            return None

    sys.meta_path.insert(0, Block())
    try:
        import PySide6  # noqa: F401
    except ImportError:
        pass
    else:
        raise SystemExit("the import blocker does not work")

    import numpy as np

    import amrst
    import amrst.bench
    import amrst.cli
    import amrst.io
    import amrst.pipeline
    import amrst.simulate
    from amrst.types import Cloud, apply_transform, invert_transform, make_transform

    tree = amrst.io.read({tiny!r})
    a = np.radians(40.0)
    R = np.array([[np.cos(a), -np.sin(a), 0], [np.sin(a), np.cos(a), 0], [0, 0, 1]])
    T_true = make_transform(R, [2.0, -1.0, 0.2])
    rng = np.random.default_rng(1)
    src = apply_transform(invert_transform(T_true), tree.xyz)
    src = src + rng.normal(0, 0.003, src.shape)
    result = amrst.register(Cloud(tree.xyz), Cloud(src))
    err = np.abs(result.T_target_source - T_true).max()
    assert err < 0.05, err
    loaded = sorted(m for m in sys.modules if m.split(".")[0] in BLOCKED)
    assert not loaded, loaded
    print("OK", len(result.matches.candidates))
    """
)


@pytest.mark.slow
def test_engine_runs_without_qt_or_pyvista() -> None:
    tiny = str(ROOT / "tests" / "data" / "tiny_tree" / "tree.ply")
    script = SCRIPT.format(blocked=BLOCKED, tiny=tiny)
    proc = subprocess.run(
        [sys.executable, "-W", "error", "-c", script],
        capture_output=True,
        text=True,
        timeout=240,
        cwd=ROOT,
        check=False,
    )
    assert proc.returncode == 0, proc.stdout + proc.stderr
    assert proc.stdout.startswith("OK")
