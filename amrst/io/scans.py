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
``scanner_origin`` (where the scanner stood in the cloud's frame) and ``scan_index``.
Large coordinates are split into ``offset`` + small local values, as every reader does,
so georeferenced scans keep millimetres.
"""

from __future__ import annotations

import os
import re
from dataclasses import dataclass, replace
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from amrst.errors import InvalidInput
from amrst.io.common import OFFSET_STEP_M, RawCloud, shorten

if TYPE_CHECKING:
    from collections.abc import Callable, Sequence

    from amrst.types import Cloud, Transform

PathLike = str | os.PathLike[str]
_SPEC = re.compile(r"^(?P<path>.+?)#(?P<scans>[0-9][0-9 ,]*)$")


@dataclass(frozen=True, slots=True)
class ScanInfo:
    """One scan of a multi-scan file, as its header describes it.

    Attributes
    ----------
    index : int
        Position in the file, from 0 (what ``FILE#index`` selects).
    name : str
        The scan's name in the file (E57 ``name``), or ``scan <index>``.
    n_points : int
        Points stored (before invalid ones are dropped).
    T_world_scanner : (4, 4) float64
        The stored pose; the identity when the file stores none.
    has_pose : bool
    fields : tuple of str
        Per-point fields besides x, y, z (``intensity``, ``red``...).
    """

    index: int
    name: str
    n_points: int
    T_world_scanner: Transform
    has_pose: bool
    fields: tuple[str, ...]


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


def check_indices(
    path: Path, wanted: Sequence[int] | None, count: int
) -> tuple[int, ...]:
    """Return the scans to read: ``wanted`` checked against the ``count`` in the file."""
    if count == 0:
        raise InvalidInput(f"{path} holds no scan. Export the scans again.")
    if wanted is None:
        return tuple(range(count))
    bad = [i for i in wanted if not 0 <= i < count]
    if bad:
        raise InvalidInput(
            f"{path} holds {count} scan(s), numbered 0 to {count - 1}; there is no "
            f"scan {bad[0]}. Choose scans with FILE#k (amrst info {path.name} lists "
            "them)."
        )
    return tuple(wanted)


def posed_raw(
    xyz: np.ndarray,
    T_world_scanner: Transform,
    attributes: dict[str, np.ndarray],
    meta: dict[str, Any],
    *,
    posed: bool,
) -> RawCloud:
    """Return a scan as a RawCloud: moved by its pose (or not), precision kept at any offset.

    ``xyz`` (N, 3) float64 is in the scanner frame. The pose's translation may be
    georeferenced (x = 500000): it is split into a rounded offset and a small rest
    before the points are moved, so the local values stay small.
    """
    T = np.asarray(T_world_scanner, dtype=np.float64)
    meta = {**meta, "pose": tuple(tuple(float(v) for v in row) for row in T)}
    if not posed:
        return RawCloud(
            xyz, np.zeros(3), attributes, {**meta, "scanner_origin": (0.0, 0.0, 0.0)}
        )
    t = T[:3, 3]
    offset = np.floor(t / OFFSET_STEP_M) * OFFSET_STEP_M
    offset[np.abs(t) < 1e4] = 0.0
    local = xyz @ T[:3, :3].T + (t - offset)
    origin = tuple(float(v) for v in t)
    return RawCloud(local, offset, attributes, {**meta, "scanner_origin": origin})


def merge_raw(raws: Sequence[RawCloud], indices: Sequence[int]) -> RawCloud:
    """Several posed scans as one RawCloud with a ``scan_id`` attribute (file index)."""
    if len(raws) == 1:
        return raws[0]
    offset = raws[0].offset
    xyz = np.vstack([r.xyz + (r.offset - offset) for r in raws])
    names = list(dict.fromkeys(k for r in raws for k in r.attributes))
    attrs: dict[str, np.ndarray] = {}
    for name in names:
        cols = [r.attributes.get(name) for r in raws]
        dtype = np.result_type(*(c.dtype for c in cols if c is not None))
        attrs[name] = np.concatenate(
            [
                np.asarray(c, dtype) if c is not None else np.zeros(len(r.xyz), dtype)
                for c, r in zip(cols, raws, strict=True)
            ]
        )
    attrs["scan_id"] = np.concatenate(
        [np.full(len(r.xyz), i, np.uint16) for i, r in zip(indices, raws, strict=True)]
    )
    meta = {
        "n_scans": len(raws),
        "scanner_origins": tuple(
            float(v) for r in raws for v in r.meta.get("scanner_origin", (0, 0, 0))
        ),
    }
    return RawCloud(xyz, offset, attrs, meta)


def guarded(path: Path, label: str, fn: Callable[[], Any]) -> Any:
    """Run a library call on ``path``; any library error becomes one InvalidInput line."""
    from amrst.errors import AmrstError

    try:
        return fn()
    except AmrstError:
        raise
    except PermissionError as exc:
        raise InvalidInput(
            f"Cannot read {path}: permission denied: fix the file's permissions or "
            "copy it somewhere readable."
        ) from exc
    except MemoryError as exc:
        raise InvalidInput(f"{path} is too large to load into memory.") from exc
    except Exception as exc:  # libE57 messages run over several lines: one line here
        text = " ".join(str(exc).replace("****", " ").split())
        raise InvalidInput(
            f"Could not read {path}: {shorten(text, 200)} "
            f"({type(exc).__name__}). The file looks corrupt or truncated, or is "
            f"not really a {label} file; export it again."
        ) from exc


def _multi_module(path: Path) -> Any:
    suffix = path.suffix.lower()
    if suffix == ".e57":
        from amrst.io import e57

        return e57
    if suffix == ".ptx":
        from amrst.io import ptx

        return ptx
    return None


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
        replace(finish(raw, path, module.LABEL, True), name=f"{path.name}#{i}")
        for i, raw in raws
    ]


def _check(path: Path) -> None:
    """Make the checks every reader makes first: exists, a file, not empty, readable."""
    from amrst.io import _check_readable

    try:
        _check_readable(path)
    except PermissionError as exc:
        raise InvalidInput(
            f"Cannot read {path}: permission denied: fix the file's permissions or "
            "copy it somewhere readable."
        ) from exc
