"""Writing LAS and LAZ files through laspy (LAZ via lazrs); private to amrst.io.

Attributes named like a standard LAS dimension go there; every other attribute goes
into an extra-bytes dimension. A standard-named attribute whose values the standard
field cannot hold (e.g. a float intensity of 0.37) is also stored exactly in an
extra dimension ``amrst_<name>``, which the reader (:mod:`amrst.io.las`) maps back.
"""

from __future__ import annotations

import logging
from typing import TYPE_CHECKING, Any

import numpy as np

from amrst.io.common import flat_attributes, storable
from amrst.io.las import PREFIX, all_standard_names, dimension_names

if TYPE_CHECKING:
    from collections.abc import Mapping
    from pathlib import Path

    from amrst.types import Cloud

logger = logging.getLogger(__name__)

_CANDIDATE_FORMATS = (0, 1, 2, 3, 6, 7, 8)
_DEFAULT_SCALE_M = 1e-4  # 0.1 mm: keeps millimetres after any transform
_INT32_MAX = 2**31 - 1


def _choose_format(names: set[str], meta: Mapping[str, Any]) -> int:
    """Pick the point format holding most standard-named attributes (file's first)."""
    wanted = names & all_standard_names()
    preferred: Any = meta.get("las_point_format")
    candidates = list(_CANDIDATE_FORMATS)
    if preferred in range(11):
        candidates.insert(0, int(preferred))
    scored = [
        (len(wanted & dimension_names(fmt)), -i, fmt)
        for i, fmt in enumerate(candidates)
    ]
    return max(scored)[2]


def _quantize(cloud: Cloud) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Scales (3,), offsets (3,) and the (N, 3) int32 coordinates for the header."""
    scales = np.minimum(
        np.asarray(cloud.meta.get("las_scales", [_DEFAULT_SCALE_M] * 3), float),
        _DEFAULT_SCALE_M,
    )
    offsets = np.round(cloud.offset)
    if len(cloud) == 0:
        return scales, offsets, np.zeros((0, 3), np.int32)
    lo, hi = cloud.xyz.min(axis=0), cloud.xyz.max(axis=0)
    if np.any(
        np.maximum(abs(lo), abs(hi)) + abs(cloud.offset - offsets) > _INT32_MAX * scales
    ):
        offsets = np.round(cloud.offset + (lo + hi) / 2)  # re-centre on the points
    reach = np.maximum(
        abs(lo + cloud.offset - offsets), abs(hi + cloud.offset - offsets)
    )
    too_fine = reach > 0.99 * _INT32_MAX * scales
    if too_fine.any():
        coarse = 10.0 ** np.ceil(np.log10(reach / (0.99 * _INT32_MAX)))
        scales = np.where(too_fine, coarse, scales)
        logger.warning(
            "The cloud spans %s m; LAS scale coarsened to %s m to fit 32-bit integers.",
            np.round(hi - lo).tolist(),
            scales.tolist(),
        )
    local = cloud.xyz + (cloud.offset - offsets)
    return scales, offsets, np.round(local / scales).astype(np.int32)


def _fit(dim: Any, values: np.ndarray) -> tuple[np.ndarray, bool]:
    """Values cast for a standard dimension, and whether the cast kept them exactly."""
    data = np.asarray(values, dtype=np.float64)
    if dim.kind.name == "FloatingPoint":
        return data, bool(np.array_equal(data, values, equal_nan=True))
    exact = bool(
        np.all(np.isfinite(data))
        and np.all(data == np.round(data))
        and np.all((data >= dim.min) & (data <= dim.max))
    )
    fitted = np.clip(np.round(np.nan_to_num(data)), dim.min, dim.max)
    return fitted.astype(dim.dtype or np.uint8), exact


def _split(cloud: Cloud, point_format: int) -> tuple[dict[str, Any], dict[str, Any]]:
    """Attributes for standard dimensions and for extra dimensions."""
    import laspy

    fmt = laspy.PointFormat(point_format)
    standard: dict[str, np.ndarray] = {}
    extra: dict[str, np.ndarray] = {}
    for name, values in flat_attributes(cloud).items():
        if name in dimension_names(point_format):
            standard[name], exact = _fit(fmt.dimension_by_name(name), values)
            if exact:
                continue
            name = PREFIX + name
        value = storable(values, allow_int64=True, name=name)
        if value is not None:
            if len(name) > 32:
                logger.warning(
                    "LAS extra dimension name %r cut to 32 characters.", name
                )
            extra[name[:32]] = value
    return standard, extra


def write_las(
    path: Path, cloud: Cloud, *, binary: bool = True, compress: bool = False
) -> None:
    """Write LAS (or LAZ when ``compress``) keeping every attribute; see module docs."""
    import laspy

    point_format = _choose_format(set(flat_attributes(cloud)), cloud.meta)
    standard, extra = _split(cloud, point_format)
    version = "1.4" if cloud.meta.get("las_version") == "1.4" else None
    header = laspy.LasHeader(point_format=point_format, version=version)
    header.scales, header.offsets, ints = _quantize(cloud)
    header.add_extra_dims(
        [laspy.ExtraBytesParams(name, v.dtype.str[1:]) for name, v in extra.items()]
    )
    for user_id, record_id, description, data in cloud.meta.get("las_vlrs", ()):
        header.vlrs.append(laspy.VLR(user_id, record_id, description, data))
    las = laspy.LasData(
        header, points=laspy.ScaleAwarePointRecord.zeros(len(cloud), header=header)
    )
    las.X, las.Y, las.Z = ints[:, 0], ints[:, 1], ints[:, 2]
    for name, values in {**standard, **extra}.items():
        las[name] = values
    with open(path, "wb") as f:
        las.write(f, do_compress=compress)
