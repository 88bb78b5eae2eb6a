"""Parameters to and from JSON, with a schema version, and named presets.

Files written by an older version keep loading: unknown keys are refused with a clear
message, missing keys take the current defaults, and ``schema_version`` says which
layout a file has (see tests/core/data/params_v1.json).
"""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path
from typing import TYPE_CHECKING, Any

from amrst.atomic import write_json_atomic
from amrst.errors import InvalidInput
from amrst.pipeline import RegistrationParams
from amrst.resources import resource_path

if TYPE_CHECKING:
    import os

SCHEMA_VERSION = 1
PRESETS_DIR = resource_path("presets")


def params_to_dict(params: RegistrationParams) -> dict[str, Any]:
    """Nested plain dict (JSON-ready) with ``schema_version``."""
    out: dict[str, Any] = {"schema_version": SCHEMA_VERSION}
    for f in dataclasses.fields(params):
        stage = getattr(params, f.name)
        out[f.name] = {
            g.name: list(v) if isinstance(v := getattr(stage, g.name), tuple) else v
            for g in dataclasses.fields(stage)
        }
    return out


def params_from_dict(data: dict[str, Any]) -> RegistrationParams:
    """Build parameters from a dict; missing values take the defaults.

    Raises
    ------
    InvalidInput
        Unknown stage or parameter names, a newer schema, or values out of range.
    """
    version = data.get("schema_version", SCHEMA_VERSION)
    if not isinstance(version, int) or version > SCHEMA_VERSION:
        raise InvalidInput(
            f"Parameter file schema_version {version!r} is newer than this AMRST "
            f"({SCHEMA_VERSION}); update AMRST Studio or remove the newer settings."
        )
    defaults = RegistrationParams()
    stages = {}
    for f in dataclasses.fields(defaults):
        given = data.get(f.name, {})
        if not isinstance(given, dict):
            raise InvalidInput(f"Parameters '{f.name}' must be a table of values.")
        stage = getattr(defaults, f.name)
        names = {g.name: g for g in dataclasses.fields(stage)}
        unknown = set(given) - set(names)
        if unknown:
            raise InvalidInput(
                f"Unknown parameter(s) {sorted(unknown)} in '{f.name}'; "
                f"known ones are {sorted(names)}."
            )
        values = {k: tuple(v) if isinstance(v, list) else v for k, v in given.items()}
        for key, value in values.items():
            _check_value(f.name, names[key], getattr(stage, key), value)
        try:
            stages[f.name] = dataclasses.replace(stage, **values)
        except (TypeError, ValueError) as exc:
            raise InvalidInput(f"Bad value in parameters '{f.name}': {exc}") from exc
    unknown_stages = set(data) - set(stages) - {"schema_version", "name", "description"}
    if unknown_stages:
        raise InvalidInput(f"Unknown parameter section(s) {sorted(unknown_stages)}.")
    return RegistrationParams(**stages)


def _check_value(
    stage: str, f: dataclasses.Field[Any], default: Any, value: Any
) -> None:
    """Type and range of one value against the field's default and metadata."""
    name = f"{stage}.{f.name}"
    meta = f.metadata
    if isinstance(default, bool):
        ok = isinstance(value, bool)
    elif isinstance(default, int):
        ok = isinstance(value, int) and not isinstance(value, bool)
    elif isinstance(default, float):
        ok = isinstance(value, (int, float)) and not isinstance(value, bool)
    elif isinstance(default, str):
        ok = isinstance(value, str)
    elif isinstance(default, tuple):
        ok = isinstance(value, tuple) and all(
            isinstance(v, type(default[0])) for v in value
        )
    else:
        ok = True
    if not ok:
        raise InvalidInput(
            f"Parameter {name} must be of type {type(default).__name__}, got {value!r}."
        )
    if "choices" in meta and value not in meta["choices"]:
        raise InvalidInput(
            f"Parameter {name} must be one of {list(meta['choices'])}, got {value!r}."
        )
    if (
        isinstance(value, (int, float))
        and not isinstance(value, bool)
        and value == value
    ):
        lo, hi = meta.get("min"), meta.get("max")
        if (lo is not None and value < lo) or (hi is not None and value > hi):
            raise InvalidInput(
                f"Parameter {name} = {value} is outside its range [{lo}, {hi}]."
            )


def save_params(path: str | os.PathLike[str], params: RegistrationParams) -> None:
    """Write parameters as JSON, atomically."""
    write_json_atomic(path, params_to_dict(params))


def load_params(path: str | os.PathLike[str]) -> RegistrationParams:
    """Read a parameter JSON file (clear InvalidInput on any problem)."""
    path = Path(path)
    if not path.is_file():
        raise InvalidInput(f"Parameter file not found: {path}. Check the path.")
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise InvalidInput(
            f"Cannot read parameter file {path}: {exc}. It must be JSON."
        ) from exc
    if not isinstance(data, dict):
        raise InvalidInput(f"Parameter file {path} must hold a JSON object.")
    return params_from_dict(data)


def list_presets() -> dict[str, Path]:
    """Preset name -> file, from resources/presets/*.json."""
    if not PRESETS_DIR.is_dir():
        return {}
    out = {}
    for p in sorted(PRESETS_DIR.glob("*.json")):
        try:
            name = json.loads(p.read_text(encoding="utf-8")).get("name", p.stem)
        except (OSError, json.JSONDecodeError):
            continue
        out[str(name)] = p
    return out


def load_preset(name: str) -> RegistrationParams:
    """Parameters of a named preset."""
    presets = list_presets()
    if name not in presets:
        raise InvalidInput(f"No preset named {name!r}; available: {sorted(presets)}.")
    return load_params(presets[name])
