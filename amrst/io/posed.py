"""Shared by the multi-scan readers (E57, PTX): scan headers, poses, errors; private.

:mod:`amrst.io.scans` is the public side (specs, listing, reading chosen scans).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np

from amrst.errors import InvalidInput
from amrst.io.common import OFFSET_STEP_M, RawCloud, shorten

if TYPE_CHECKING:
    from collections.abc import Callable, Sequence
    from pathlib import Path

    from amrst.types import Transform


@dataclass(frozen=True, slots=True)
class ScanInfo:
    """One scan of a multi-scan file, as its header describes it.

    Attributes
    ----------
    index : int
        Position in the file, from 0 (what ``FILE#index`` selects).
    name : str
        The scan's name in the file (E57 ``name``), or "" when it has none.
    n_points : int
        Points stored (before invalid ones are dropped).
    T_world_scanner : (4, 4) float64
        The stored pose; the identity when the file stores none.
    has_pose : bool
    fields : tuple of str
        Per-point fields besides x, y, z (``intensity``, ``red``...).
    scanner_xyz : (float, float, float) or None
        Where the scanner stood as the file says, in its coordinates: the pose's
        position, or a PTX header's for points written already registered; None
        when the file does not say.
    """

    index: int
    name: str
    n_points: int
    T_world_scanner: Transform
    has_pose: bool
    fields: tuple[str, ...]
    scanner_xyz: tuple[float, float, float] | None = None


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


def pose_problem(T: np.ndarray) -> str | None:
    """Say what makes a stored 4x4 pose unusable, or None for a rigid move within 1e9 m."""
    from amrst.types import MAX_COORD_M, rigid_problem

    T = np.asarray(T, dtype=np.float64)
    problem = rigid_problem(T)
    if problem is not None:
        return f"the scan's stored pose {problem}"
    if not np.abs(T[:3, 3]).max() <= MAX_COORD_M:
        return f"the scan's stored position lies beyond {MAX_COORD_M:g} m"
    return None


def check_pose(T: np.ndarray, where: str) -> np.ndarray:
    """Return a stored 4x4 pose as float64 if it is usable (:func:`pose_problem`).

    Raises
    ------
    InvalidInput
        Naming ``where`` (the file and scan) and what is wrong: a zero quaternion, a
        scale, NaN, or a position beyond 1e9 m.
    """
    problem = pose_problem(T)
    if problem is not None:
        raise InvalidInput(
            f"{where}: {problem}. Export the scan again with its pose, or without one, "
            "or leave it out."
        )
    return np.asarray(T, dtype=np.float64)


def posed_raw(
    xyz: np.ndarray,
    T_world_scanner: Transform,
    attributes: dict[str, np.ndarray],
    meta: dict[str, Any],
    *,
    posed: bool,
    where: str,
) -> RawCloud:
    """Return a scan as a RawCloud: moved by its pose (or not), precision kept at any offset.

    ``xyz`` (N, 3) float64 is in the scanner frame. The pose's translation may be
    georeferenced (x = 500000): it is split into a rounded offset and a small rest
    before the points are moved, so the local values stay small. A pose that is no
    rigid move within 1e9 m is refused, naming ``where`` (:func:`check_pose`): the
    scans read are checked, not every scan of the file.
    """
    T = check_pose(T_world_scanner, where)
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


def read_all_posed(
    read_raw_scans: Callable[
        [Path, Sequence[int] | None, bool], list[tuple[int, RawCloud]]
    ],
    path: Path,
) -> RawCloud:
    """Every scan of the file, posed, in one cloud (``scan_id`` when more than one).

    ``read_raw_scans`` is the format's reader of chosen scans (E57, PTX).
    """
    raws = read_raw_scans(path, None, True)
    return merge_raw([r for _, r in raws], [i for i, _ in raws])


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
    except Exception as exc:
        raise InvalidInput(
            f"Could not read {path}: {library_reason(exc)}. It is not a readable "
            f"{label.upper()} file (corrupt or truncated): export it again."
        ) from exc


def library_reason(exc: Exception) -> str:
    """Return a library error's reason on one line, without its debug text.

    libE57 repeats its reason ("Got an e57 exception: ...") and appends "Debug info:"
    with source file names and line numbers, over several lines; a user needs only
    the reason.
    """
    text = " ".join(str(exc).replace("****", " ").split())
    for cut in (" Got an e57 exception", " Debug info"):
        text = text.split(cut, 1)[0]
    return shorten(text.rstrip(" ."), 160) or type(exc).__name__
