"""ASTM E57 files through ``pye57`` (libE57Format); private to amrst.io.

An E57 file holds several scans (``data3D``), each with its points in the scanner's
frame (cartesian or spherical), optional intensity and colour, and a pose (a unit
quaternion and a translation: ``T_world_scanner``). :func:`read_e57` (the ``.e57`` entry
of ``amrst.io``) reads every scan posed into one cloud with a ``scan_id`` attribute;
:func:`amrst.io.scans.read_scans` reads chosen scans as separate clouds
(``plot.e57#0,2``). Points flagged invalid (``cartesianInvalidState`` /
``sphericalInvalidState``) are dropped. Attributes: ``intensity`` (float32, as
stored), ``red``, ``green``, ``blue`` (uint8).
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

import numpy as np

from amrst.errors import InvalidInput
from amrst.io.posed import ScanInfo, check_indices, guarded, posed_raw, read_all_posed

if TYPE_CHECKING:
    from collections.abc import Sequence
    from pathlib import Path

    from amrst.io.common import RawCloud

LABEL = "e57"
_COLOURS = (("colorRed", "red"), ("colorGreen", "green"), ("colorBlue", "blue"))


def _pose(header: Any) -> np.ndarray:
    T = np.eye(4)
    if header.has_pose():
        T[:3, :3] = np.asarray(header.rotation_matrix, dtype=np.float64)
        T[:3, 3] = np.asarray(header.translation, dtype=np.float64)
    return T


def _info(e57: Any, index: int) -> ScanInfo:
    header = e57.get_header(index)
    node = header.node
    name = node["name"].value() if node.isDefined("name") else ""
    fields = []
    if "intensity" in header.point_fields:
        fields.append("intensity")
    if all(f in header.point_fields for f, _ in _COLOURS):
        fields += [name for _, name in _COLOURS]
    T, posed = _pose(header), bool(header.has_pose())
    at = (float(T[0, 3]), float(T[1, 3]), float(T[2, 3])) if posed else None
    return ScanInfo(
        index, str(name), int(header.point_count), T, posed, tuple(fields), at
    )


# Every E57 file starts with this file signature (ASTM E2807, section 9.3).
_SIGNATURE = b"ASTM-E57"


def _open(path: Path) -> Any:
    """Open ``path`` with pye57, after checking that it is an E57 file at all.

    libE57 answers a file of another kind with a checksum or "internal state" error
    and several lines of debug text; the signature check says what is wrong instead.
    """
    from amrst.extras import require

    pye57 = require("pye57", "reading E57 files")
    with open(path, "rb") as f:
        head = f.read(len(_SIGNATURE))
    if head != _SIGNATURE:
        raise InvalidInput(
            f"{path} is not a readable E57 file (it does not start with the E57 "
            "signature 'ASTM-E57'): export it again as E57, or give the file the "
            "extension of its real format."
        )
    return pye57.E57(str(path))


def list_scans(path: Path) -> list[ScanInfo]:
    """Every scan of the file, from its headers (no points are read)."""

    def run() -> list[ScanInfo]:
        with _open(path) as e57:
            return [_info(e57, i) for i in range(e57.scan_count)]

    result: list[ScanInfo] = guarded(path, LABEL, run)
    return result


def _read_one(e57: Any, index: int, posed: bool) -> RawCloud:
    from pye57.utils import convert_spherical_to_cartesian

    info = _info(e57, index)
    data = e57.read_scan(
        index,
        intensity="intensity" in info.fields,
        colors="red" in info.fields,
        transform=False,
        ignore_missing_fields=True,
    )
    if "cartesianX" in data:
        xyz = np.column_stack(
            [
                np.asarray(data[k], np.float64)
                for k in ("cartesianX", "cartesianY", "cartesianZ")
            ]
        )
    else:
        rae = np.column_stack(
            [
                np.asarray(data[k], np.float64)
                for k in ("sphericalRange", "sphericalAzimuth", "sphericalElevation")
            ]
        )
        xyz = convert_spherical_to_cartesian(rae)
    attributes: dict[str, np.ndarray] = {}
    if "intensity" in data:
        attributes["intensity"] = np.asarray(data["intensity"])
    for field, name in _COLOURS:
        if field in data:
            attributes[name] = np.asarray(data[field], np.uint8)
    meta = {"scan_index": index, "scan_name": info.name, "e57_has_pose": info.has_pose}
    where = f"{e57.path}#{index}"
    return posed_raw(
        xyz, info.T_world_scanner, attributes, meta, posed=posed, where=where
    )


def read_raw_scans(
    path: Path, wanted: Sequence[int] | None, posed: bool
) -> list[tuple[int, RawCloud]]:
    """Read the chosen scans (all when None) as ``(index, RawCloud)``, posed or not."""

    def run() -> list[tuple[int, RawCloud]]:
        with _open(path) as e57:
            chosen = check_indices(path, wanted, e57.scan_count)
            return [(i, _read_one(e57, i, posed)) for i in chosen]

    result: list[tuple[int, RawCloud]] = guarded(path, LABEL, run)
    return result


def read_e57(path: Path) -> RawCloud:
    """Every scan of the file, posed, in one cloud (``scan_id`` when more than one)."""
    return read_all_posed(read_raw_scans, path)
