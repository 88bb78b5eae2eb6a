"""The shape of the code shows its architecture, and stays that way.

No import cycle among the project's modules (run-time imports; imports under
``TYPE_CHECKING`` do not run), ``import amrst.simulate``
loads no benchmark or baseline, and the per-scan chain follows the step table.
"""

from __future__ import annotations

import ast
import subprocess
import sys
from pathlib import Path

import grimp
import networkx as nx
import pytest

ROOT = Path(__file__).resolve().parents[2]


@pytest.mark.parametrize("package", ["amrst", "amrst_gui"])
def test_no_import_cycles(package: str) -> None:
    graph = grimp.build_graph(package, exclude_type_checking_imports=True)
    g = nx.DiGraph()
    for module in graph.modules:
        for imported in graph.find_modules_directly_imported_by(module):
            if imported.split(".")[0] == package:
                g.add_edge(module, imported)
    # A package's __init__ re-exporting its own modules is not a cycle of design:
    # drop edges from a package to its own submodules.
    g.remove_edges_from([(a, b) for a, b in list(g.edges) if b.startswith(a + ".")])
    cycles = list(nx.simple_cycles(g))
    assert not cycles, cycles[:5]


def _loaded_after(module: str, prefixes: tuple[str, ...]) -> list[str]:
    """Modules starting with ``prefixes`` that a fresh ``import module`` loads."""
    code = (
        f"import sys, {module}; "
        f"print(sorted(m for m in sys.modules if m.startswith({prefixes!r})))"
    )
    out = subprocess.run(
        [sys.executable, "-c", code],
        capture_output=True,
        text=True,
        check=True,
        cwd=ROOT,
        timeout=120,
    ).stdout.strip()
    return ast.literal_eval(out)  # the list of module names the child printed


def test_simulate_loads_no_benchmark_or_baseline() -> None:
    loaded = _loaded_after(
        "amrst.simulate", ("amrst.bench", "amrst.baselines", "open3d")
    )
    assert loaded == [], loaded


def test_the_command_line_starts_without_readers_or_kd_trees() -> None:
    # Every command starts by importing amrst.cli: each reader and scipy.spatial are
    # loaded by the commands that use them.
    loaded = _loaded_after("amrst.cli", ("amrst.io", "scipy.spatial", "amrst.pipeline"))
    assert loaded == [], loaded


def test_one_stage_loads_only_what_it_needs() -> None:
    prefixes = (
        "amrst.pipeline",
        "amrst.bench",
        "amrst.baselines",
        "amrst.cli",
        "amrst.io",
    )
    loaded = _loaded_after("amrst.stages.fine", prefixes)
    assert loaded == [], loaded


def test_per_scan_chain_follows_the_step_table(tiny_tree) -> None:
    from amrst.params import RegistrationParams
    from amrst.pipeline import STEPS, analyse_scan

    params = RegistrationParams()
    item = tiny_tree
    for step in STEPS:
        if step.per_scan:
            item = step.run(item, params)
    whole = analyse_scan(tiny_tree, params)
    assert whole.keypoints is not None
    assert item.keypoints is not None
    assert (whole.keypoints.xyz == item.keypoints.xyz).all()
    assert [s.name for s in STEPS if s.per_scan] == ["separate", "skeleton"]
