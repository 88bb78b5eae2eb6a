"""Files that hold several scans (E57, PTX): list them, choose some, read them posed.

A *scan spec* names the scans to read: ``plot.e57`` (every scan of the file),
``plot.e57#2`` (scan 2, counted from 0), ``plot.e57#0,2`` (scans 0 and 2); the same for
``.ptx``. Any other file is one scan (``tree.laz``). :func:`read_scans` returns one
:class:`~amrst.types.Cloud` per scan; :func:`list_scans` tells what a file holds without
reading its points.

Each scan is read *posed* (its points moved by the pose the file stores, so the scans of
one file line up, in georeferenced coordinates when the poses are) or, with
``posed=False``, in the scanner's own frame. Either way the cloud's ``meta`` keeps
``pose`` (the stored 4x4 ``T_world_scanner``, row-major nested tuples),
``scanner_origin`` (where the scanner stood, in the file's coordinates: the cloud's
world frame) and ``scan_index``.
Large coordinates are split into ``offset`` + small local values, as every reader does,
so georeferenced scans keep millimetres.
"""

from __future__ import annotations

import importlib
import os
import re
from dataclasses import replace
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from amrst.errors import InvalidInput
from amrst.io.posed import ScanInfo

__all__ = [
    "SEVERAL_SCANS",
    "ScanInfo",
    "file_stamp",
    "list_scans",
    "names_several",
    "one_scan_specs",
    "read_scans",
    "split_spec",
]

if TYPE_CHECKING:
    from collections.abc import Sequence

    from amrst.io.common import RawCloud
    from amrst.types import Cloud

PathLike = str | os.PathLike[str]
#: The extensions of files that may hold several scans.
SEVERAL_SCANS = (".e57", ".ptx")
_SPEC = re.compile(r"^(?P<path>.+?)#(?P<scans>[0-9][0-9 ,]*)$")


def split_spec(spec: PathLike) -> tuple[Path, tuple[int, ...] | None]:
    """Split ``plot.e57#0,2`` into the path and the scan indices (None: all scans).

    Raises
    ------
    InvalidInput
        A ``#`` part that is not a list of scan numbers.
    """
    text = os.fspath(spec)
    m = _SPEC.match(text)
    if m is None:
        if "#" in Path(text).name and not Path(text).exists():
            raise InvalidInput(
                f"{text!r}: after '#' give scan numbers counted from 0, e.g. "
                "plot.e57#2 or plot.e57#0,2 (amrst info plot.e57 lists them)."
            )
        return Path(text), None
    parts = [p for p in re.split(r"[ ,]+", m.group("scans")) if p]
    if not parts:
        raise InvalidInput(f"{text!r}: no scan number after '#'.")
    return Path(m.group("path")), tuple(int(p) for p in parts)


def names_several(spec: PathLike) -> bool:
    """Tell whether a spec may name several scans: a whole E57 or PTX file, or ``#i,j``."""
    text = os.fspath(spec)
    m = _SPEC.match(text)
    if Path(m["path"] if m else text).suffix.lower() not in SEVERAL_SCANS:
        return False
    return m is None or "," in m["scans"]


def _multi_module(path: Path) -> Any:
    """Return the reader module of a file of several scans (None: one scan a file)."""
    suffix = path.suffix.lower()
    if suffix not in SEVERAL_SCANS:
        return None
    return importlib.import_module(f"amrst.io.{suffix[1:]}")


def list_scans(path: PathLike) -> list[ScanInfo]:
    """List the scans a file holds (one for single-scan formats), without reading points.

    Raises
    ------
    InvalidInput
        Missing, empty, corrupt or truncated file, or an unsupported extension.
    """
    from amrst import io

    path = Path(path)
    module = _multi_module(path)
    if module is None:
        cloud = io.read(path)
        fields = tuple(cloud.attributes)
        return [ScanInfo(0, cloud.name, len(cloud), np.eye(4), False, fields)]
    _check(path)
    infos: list[ScanInfo] = module.list_scans(path)
    return infos


def one_scan_specs(specs: Sequence[PathLike]) -> list[tuple[str, str]]:
    """Split specs into one spec per scan they name, with its name; no points read.

    ``plot.e57`` of three scans gives ``plot.e57#0``, ``plot.e57#1``, ``plot.e57#2``; a
    spec of one scan is given back as it is. The name is the scan's in its file (an
    E57 setup's), or "" (a file of one scan, a PTX scan). Each file is checked as
    every reader checks it first (there, a file, not empty, a known extension), and
    the scan numbers against its headers, listed once however many specs name the
    file (a PTX file is read through to list its scans).

    Raises
    ------
    InvalidInput
        As :func:`read_scans` for a bad spec, a file it cannot read, or a scan number
        the file does not have.
    """
    from amrst.io.posed import check_indices

    listed: dict[Path, list[ScanInfo]] = {}  # the scans of each file of several
    out: list[tuple[str, str]] = []
    for spec in specs:
        text = os.fspath(spec)
        path, wanted = split_spec(text)
        _check(path)
        if _multi_module(path) is None:
            if wanted not in (None, (0,)):
                raise InvalidInput(
                    f"{path.name} holds one scan; '#' selects scans of E57 and PTX "
                    "files only."
                )
            out.append((text, ""))
            continue
        if path not in listed:
            listed[path] = list_scans(path)
        infos = listed[path]
        indices = check_indices(path, wanted, len(infos))
        base = text if wanted is None else text.rsplit("#", 1)[0]
        if len(indices) == 1:
            out.append((text, infos[indices[0]].name))
        else:
            out += [(f"{base}#{k}", infos[k].name) for k in indices]
    return out


def file_stamp(spec: PathLike) -> tuple[int, int] | None:
    """Return the size and modification time (ns) of the file a spec names.

    None when the file cannot be looked at (gone, or the spec is not a file's).
    """
    try:
        info = split_spec(spec)[0].stat()
    except (OSError, InvalidInput):
        return None
    return info.st_size, info.st_mtime_ns


def read_scans(spec: PathLike, *, posed: bool = True) -> list[Cloud]:
    """Read the scans a spec names (``plot.e57#0,2``, ``plot.ptx``, ``tree.laz``).

    Parameters
    ----------
    spec : str or os.PathLike
        A file, optionally followed by ``#`` and scan numbers counted from 0.
    posed : bool
        Move each scan by its stored pose (default), or keep scanner coordinates.

    Returns
    -------
    list of Cloud
        One cloud per scan, named ``file#k`` for multi-scan files, with ``meta``
        ``pose``, ``scanner_origin`` and ``scan_index``.

    Raises
    ------
    InvalidInput
        Bad spec, a scan number the file does not have, or a file the readers refuse.
    """
    from amrst import io
    from amrst.io import _finish as finish

    path, wanted = split_spec(spec)
    module = _multi_module(path)
    if module is None:
        if wanted not in (None, (0,)):
            raise InvalidInput(
                f"{path.name} holds one scan; '#' selects scans of E57 and PTX files "
                "only."
            )
        return [io.read(path)]
    _check(path)
    raws: list[tuple[int, RawCloud]] = module.read_raw_scans(path, wanted, posed)
    return [
        replace(
            finish(raw, path, module.LABEL, f"scan #{i} of {path}"),
            name=f"{path.name}#{i}",
        )
        for i, raw in raws
    ]


def _check(path: Path) -> None:
    """Make the checks every reader makes first: exists, a file, not empty, readable."""
    from amrst.io import check_readable

    try:
        check_readable(path)
    except PermissionError as exc:
        raise InvalidInput(
            f"Cannot read {path}: permission denied: fix the file's permissions or "
            "copy it somewhere readable."
        ) from exc
