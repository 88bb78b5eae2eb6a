"""AMRST: marker-free registration of two terrestrial laser scans of one tree.

Public API (the app, the CLI and the benchmark use only these names)::

    cloud = amrst.io.read("scan.laz")
    result = amrst.register(target, source, params=None, reporter=None)
    result.T_target_source  # (4, 4) maps source coordinates into the target frame
    multi = amrst.register_scans([ref, scan2, scan3], reference=0)  # several scans
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

from amrst.errors import AmrstError, Cancelled, InvalidInput, RegistrationFailed
from amrst.types import Cloud

if TYPE_CHECKING:
    from amrst.multiscan import MultiScanResult, register_scans
    from amrst.params import RegistrationParams
    from amrst.pipeline import RegistrationResult, register

# The pipeline is loaded on first use, so that importing one stage, the readers or
# the simulator does not load every stage (PEP 562).
_LAZY = {
    "RegistrationParams": "amrst.params",
    "RegistrationResult": "amrst.pipeline",
    "register": "amrst.pipeline",
    "MultiScanResult": "amrst.multiscan",
    "register_scans": "amrst.multiscan",
}


def __getattr__(name: str) -> Any:
    if name in _LAZY:
        import importlib

        return getattr(importlib.import_module(_LAZY[name]), name)
    raise AttributeError(f"module 'amrst' has no attribute {name!r}")


__version__ = "0.1.0"
__all__ = [
    "AmrstError",
    "Cancelled",
    "Cloud",
    "InvalidInput",
    "MultiScanResult",
    "RegistrationFailed",
    "RegistrationParams",
    "RegistrationResult",
    "__version__",
    "register",
    "register_scans",
]
