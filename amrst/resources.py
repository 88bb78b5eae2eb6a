"""Where the data shipped with AMRST Studio lives: presets, the sample pair, icons.

A wheel installs ``resources/`` as the package ``amrst_resources`` (pyproject.toml maps
the folder onto that name, as an editable install does); a plain checkout on
``PYTHONPATH`` has only the folder beside the packages.
"""

from __future__ import annotations

import importlib.util
from pathlib import Path

PACKAGE = "amrst_resources"


def resources_root() -> Path:
    """Return the folder holding ``presets/``, ``sample/`` and ``icons/``.

    Returns
    -------
    Path
        The installed ``amrst_resources`` package when there is one, else the
        checkout's ``resources/`` folder (which may not exist in a broken install).
    """
    spec = importlib.util.find_spec(PACKAGE)
    if spec is not None and spec.submodule_search_locations:
        return Path(next(iter(spec.submodule_search_locations)))
    return Path(__file__).resolve().parent.parent / "resources"


def resource_path(*parts: str) -> Path:
    """Return the path of a shipped file or folder, e.g. ``resource_path("sample", "target.ply")``.

    Parameters
    ----------
    *parts : str
        Path components below the resources folder.

    Returns
    -------
    Path
    """
    return resources_root().joinpath(*parts)
