"""Parameters to and from JSON, with a schema version, and named presets.

Files written by an older version keep loading: unknown keys are refused with a clear
message, missing keys take the current defaults, and ``schema_version`` says which
layout a file has (see tests/core/data/params_v1.json).

Values that mean "automatic" are NaN in memory (``separate.intensity_threshold``) and
``null`` in the files written here, so strict JSON parsers read them; files holding a
bare ``NaN`` (written by older versions) keep loading.
"""

from __future__ import annotations

import dataclasses
import json
import math
from typing import TYPE_CHECKING, Any

from amrst.errors import InvalidInput
from amrst.files.atomic import write_json_atomic
from amrst.files.safefile import load_json_file
from amrst.params.model import RegistrationParams
from amrst.resources import resource_path

if TYPE_CHECKING:
    import os
    from pathlib import Path

SCHEMA_VERSION = 1
MAX_LIST_ITEMS = 8  # a list parameter (e.g. separate.scales_k) holds a few values
PRESETS_DIR = resource_path("presets")


def _json_value(value: Any) -> Any:
    """Return ``value`` as strict JSON holds it: lists for tuples, None for NaN/inf."""
    if isinstance(value, tuple):
        return [_json_value(v) for v in value]
    if isinstance(value, float) and not math.isfinite(value):
        return None
    return value


def params_to_dict(params: RegistrationParams) -> dict[str, Any]:
    """Nested plain dict (strict-JSON-ready) with ``schema_version``.

    NaN ("automatic", e.g. ``separate.intensity_threshold``) becomes None, written as
    ``null``; :func:`params_from_dict` reads None back as that default.
    """
    out: dict[str, Any] = {"schema_version": SCHEMA_VERSION}
    for f in dataclasses.fields(params):
        stage = getattr(params, f.name)
        out[f.name] = {
            g.name: _json_value(getattr(stage, g.name))
            for g in dataclasses.fields(stage)
        }
    return out


def params_from_dict(data: dict[str, Any]) -> RegistrationParams:
    """Build parameters from a dict; missing values take the defaults.

    Raises
    ------
    InvalidInput
        Unknown stage or parameter names, a bad or newer schema, values of the wrong
        type, not finite or out of range, or values that contradict each other.
    """
    version = data.get("schema_version", SCHEMA_VERSION)
    if isinstance(version, bool) or not isinstance(version, int) or version < 1:
        raise InvalidInput(
            f"Parameter file schema_version must be an integer of 1 or more (this "
            f"AMRST writes {SCHEMA_VERSION}), got {version!r}; write it as a number "
            f'without quotes, e.g. "schema_version": {SCHEMA_VERSION}.'
        )
    if version > SCHEMA_VERSION:
        raise InvalidInput(
            f"Parameter file schema_version {version!r} is newer than this AMRST "
            f"({SCHEMA_VERSION}); update AMRST Studio or remove the newer settings."
        )
    defaults = RegistrationParams()
    stages = {}
    for f in dataclasses.fields(defaults):
        given = data.get(f.name, {})
        if not isinstance(given, dict):
            raise InvalidInput(
                f"Parameters '{f.name}' must be a table of values, e.g. "
                f'"{f.name}": {{...}} as in the params.json that amrst register writes.'
            )
        stage = getattr(defaults, f.name)
        names = {g.name: g for g in dataclasses.fields(stage)}
        unknown = set(given) - set(names)
        if unknown:
            raise InvalidInput(
                f"Unknown parameter(s) {sorted(unknown)} in '{f.name}'; "
                f"known ones are {sorted(names)}."
            )
        values = {k: tuple(v) if isinstance(v, list) else v for k, v in given.items()}
        for key, value in list(values.items()):
            default = getattr(stage, key)
            if _is_automatic(default) and (value is None or is_nan(value)):
                values[key] = default  # null or NaN: "automatic", the default itself
                continue
            _check_value(f.name, names[key], default, value)
        try:
            stages[f.name] = dataclasses.replace(stage, **values)
        except (TypeError, ValueError) as exc:
            raise InvalidInput(f"Bad value in parameters '{f.name}': {exc}") from exc
    unknown_stages = set(data) - set(stages) - {"schema_version", "name", "description"}
    if unknown_stages:
        raise InvalidInput(
            f"Unknown parameter section(s) {sorted(unknown_stages)[:5]}; known ones "
            f"are {sorted(stages)}. Check the spelling, or that this is a parameter "
            "file (not a truth or metrics file)."
        )
    # Pairs that must stay in order (min_points <= max_points, ...) are checked by
    # the stages themselves, so parameters built in code or in the app are too.
    return RegistrationParams(**stages)


def is_nan(value: Any) -> bool:
    """Tell a float NaN (a parameter's "automatic") from any other value."""
    return isinstance(value, float) and math.isnan(value)


def _is_automatic(default: Any) -> bool:
    """Tell a NaN default: for such a field NaN (null in a file) means "automatic"."""
    return is_nan(default)


def _finite(value: Any, as_float: bool) -> bool:
    """Tell whether a number is finite (with ``as_float``, also as a float)."""
    if isinstance(value, float):
        return math.isfinite(value)
    if as_float and isinstance(value, int) and not isinstance(value, bool):
        try:
            return math.isfinite(float(value))
        except OverflowError:
            return False
    return True  # integers and non-numbers: the type and range checks deal with them


def _type_ok(default: Any, value: Any) -> bool:
    """Tell whether ``value`` has the type of the field's ``default``.

    A bool is not an int here, an int is a float, and a tuple's items take the type
    of the default's first item.
    """
    if isinstance(default, bool):
        return isinstance(value, bool)
    if isinstance(default, int):
        return isinstance(value, int) and not isinstance(value, bool)
    if isinstance(default, float):
        return isinstance(value, (int, float)) and not isinstance(value, bool)
    if isinstance(default, str):
        return isinstance(value, str)
    if isinstance(default, tuple):
        return isinstance(value, tuple) and all(
            isinstance(v, type(default[0])) for v in value
        )
    return True


def _check_value(
    stage: str, f: dataclasses.Field[Any], default: Any, value: Any
) -> None:
    """Type and range of one value against the field's default and metadata."""
    name = f"{stage}.{f.name}"
    meta = f.metadata
    if not _type_ok(default, value):
        raise InvalidInput(
            f"Parameter {name} must be of type {type(default).__name__}, got {_short(value)}."
        )
    if "choices" in meta and value not in meta["choices"]:
        raise InvalidInput(
            f"Parameter {name} must be one of {list(meta['choices'])}, got {_short(value)}."
        )
    lo, hi = meta.get("min"), meta.get("max")
    items = value if isinstance(value, tuple) else (value,)
    as_float = isinstance(default, float) or (
        isinstance(default, tuple) and bool(default) and isinstance(default[0], float)
    )
    if not all(_finite(v, as_float) for v in items):
        span = f" in [{lo}, {hi}]" if lo is not None or hi is not None else ""
        raise InvalidInput(
            f"Parameter {name} = {_short(value)} is not a finite number (NaN and infinity "
            f"are not allowed here); give a number{span}."
        )
    # 2**31 - 1: the largest the app's parameter form can show and edit.
    if f.name == "seed" and isinstance(value, int) and not 0 <= value < 2**31:
        raise InvalidInput(
            f"Parameter {name} = {_short(value)} is {'negative' if value < 0 else 'too large'}; a "
            "seed must be an integer from 0 to 2147483647."
        )
    if isinstance(value, tuple) and not 1 <= len(value) <= MAX_LIST_ITEMS:
        raise InvalidInput(
            f"Parameter {name} has {len(value)} values; give 1 to {MAX_LIST_ITEMS}, "
            f"e.g. {list(default)}."
        )
    for item in items:  # list items too (scales_k = [100000000] is out of range)
        if (
            isinstance(item, (int, float))
            and not isinstance(item, bool)
            and ((lo is not None and item < lo) or (hi is not None and item > hi))
        ):
            which = f" (item {item})" if isinstance(value, tuple) else ""
            raise InvalidInput(
                f"Parameter {name} = {_short(value)}{which} is outside its range "
                f"[{lo}, {hi}]; give a value in that range."
            )


def _short(value: Any) -> str:
    """Repr of a value, cut to one readable line (a number can have 4,000 digits)."""
    text = repr(list(value) if isinstance(value, tuple) else value)
    return text if len(text) <= 60 else text[:57] + "..."


def save_params(path: str | os.PathLike[str], params: RegistrationParams) -> None:
    """Write parameters as JSON, atomically."""
    write_json_atomic(path, params_to_dict(params))


def load_params(path: str | os.PathLike[str]) -> RegistrationParams:
    """Read a parameter JSON file (clear InvalidInput on any problem)."""
    data = load_json_file(
        path,
        "parameter file",
        "a parameter JSON file (e.g. the params.json written by amrst register)",
    )
    if not isinstance(data, dict):
        raise InvalidInput(
            f"Parameter file {path} must hold a JSON object of sections, e.g. "
            '{"fine": {"max_iterations": 50}}; give the params.json that amrst '
            "register writes, or one like it."
        )
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
    """Parameters of a preset given by its name ("Conifer") or its file's (conifer)."""
    presets = list_presets()
    path = presets.get(name) or {p.stem: p for p in presets.values()}.get(name)
    if path is None:
        files = ", ".join(sorted(p.stem for p in presets.values()))
        raise InvalidInput(
            f"No preset named {name!r}; available: {files} (or their names: "
            f"{', '.join(repr(n) for n in sorted(presets))})."
        )
    return load_params(path)
