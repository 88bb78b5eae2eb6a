"""All settings of a registration: one frozen dataclass per stage, nested.

``RegistrationParams`` holds one field per stage (KISS-ICP style); each stage's own
``<Stage>Params`` lives in its stage module with the metadata (unit, help, range)
that drives the app's editors, the files and the parameter reference. Change a value
with ``dataclasses.replace``. Files and presets: :mod:`amrst.params.files`; the
parameter reference (``docs/parameters.md``): :mod:`amrst.params.doc`.
"""

from __future__ import annotations

from amrst.params.files import (
    SCHEMA_VERSION,
    list_presets,
    load_params,
    load_preset,
    params_from_dict,
    params_to_dict,
    save_params,
)
from amrst.params.model import RegistrationParams

__all__ = [
    "SCHEMA_VERSION",
    "RegistrationParams",
    "list_presets",
    "load_params",
    "load_preset",
    "params_from_dict",
    "params_to_dict",
    "save_params",
]
