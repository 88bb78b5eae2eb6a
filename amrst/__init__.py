"""AMRST: marker-free registration of two terrestrial laser scans of one tree.

Public API (the app, the CLI and the benchmark use only these names)::

    cloud = amrst.io.read("scan.laz")
    result = amrst.register(target, source, params=None, reporter=None)
    result.T_target_source  # (4, 4) maps source coordinates into the target frame
    multi = amrst.register_scans([ref, scan2, scan3], reference=0)  # several scans
"""

from amrst.errors import AmrstError, Cancelled, InvalidInput, RegistrationFailed
from amrst.multiscan import MultiScanResult, register_scans
from amrst.params import RegistrationParams
from amrst.pipeline import RegistrationResult, register
from amrst.types import Cloud

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
