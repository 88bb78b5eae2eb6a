"""Optional dependencies, imported on use with a one-line message when missing.

The core install (``pip install amrst-studio``) is what ``amrst register`` needs. The
app, the peer methods, campaigns on Dask and E57 files are extras; a command that needs
one names the extra to install instead of failing with a traceback.
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING

from amrst.errors import AmrstError

if TYPE_CHECKING:
    from types import ModuleType

#: The extra of ``pyproject.toml`` that brings each optional top-level module.
EXTRA_OF = {
    "open3d": "baselines",
    "dask": "campaign",
    "distributed": "campaign",
    "openpyxl": "campaign",
    "pye57": "e57",
    "PySide6": "app",
    "pyvista": "app",
    "pyvistaqt": "app",
    "superqt": "app",
}


class MissingExtra(AmrstError):
    """An optional dependency is not installed; the message names the extra."""


def _message(module: str, purpose: str) -> str:
    top = module.split(".")[0]
    return (
        f"{purpose} needs {top}, which is not installed: "
        f"pip install 'amrst-studio[{EXTRA_OF.get(top, 'all')}]'"
    )


def missing_extra(exc: ImportError, purpose: str) -> MissingExtra | None:
    """Return the :class:`MissingExtra` for an optional module's import error, if any.

    Parameters
    ----------
    exc : ImportError
        An import error caught around a command.
    purpose : str
        What needed the module, for the message, e.g. ``"amrst bench"``.

    Returns
    -------
    MissingExtra or None
        None when the missing module is not an optional dependency (a real bug).
    """
    name = getattr(exc, "name", None) or ""
    if name.split(".")[0] not in EXTRA_OF:
        return None
    return MissingExtra(_message(name, purpose))


def require(module: str, purpose: str) -> ModuleType:
    """Import ``module`` or raise :class:`MissingExtra` naming its extra.

    Parameters
    ----------
    module : str
        The module to import, e.g. ``"pye57"`` or ``"distributed"``.
    purpose : str
        What needs it, for the message, e.g. ``"reading E57 files"``.

    Returns
    -------
    ModuleType
        The imported module.

    Raises
    ------
    MissingExtra
        When the module (or one it needs) is not installed.
    """
    try:
        return importlib.import_module(module)
    except ImportError as exc:
        raise MissingExtra(_message(module, purpose)) from exc
