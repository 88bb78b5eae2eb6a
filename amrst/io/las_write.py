"""Writing LAS and LAZ files through laspy (LAZ via lazrs); private to amrst.io.

Attributes named like a standard LAS dimension go there; every other attribute goes
into an extra-bytes dimension. A standard-named attribute whose values the standard
field cannot hold (e.g. a float intensity of 0.37) is also stored exactly in an
extra dimension ``amrst_<name>``, which the reader (:mod:`amrst.io.las`) maps back.

:func:`write_las_parts` writes several clouds moved into one frame as one file, a
chunk at a time, so a registered plot of tens of millions of points is never held
twice in memory.
"""

from __future__ import annotations

import contextlib
import logging
import signal
import threading
from collections.abc import Callable
from typing import TYPE_CHECKING, Any

import numpy as np

from amrst.io.common import flat_attributes, storable
from amrst.io.las import PREFIX, all_standard_names, dimension_names

if TYPE_CHECKING:
    from collections.abc import Iterator, Mapping, Sequence
    from pathlib import Path

    from amrst.types import Cloud, Transform

logger = logging.getLogger(__name__)

_CANDIDATE_FORMATS = (0, 1, 2, 3, 6, 7, 8)
_DEFAULT_SCALE_M = 1e-4  # 0.1 mm: keeps millimetres after any transform
_INT32_MAX = 2**31 - 1
#: Points moved and written at a time by :func:`write_las_parts`.
CHUNK_POINTS = 2_000_000
#: The extra dimension holding each point's tree (``write_las_parts``'s ``labels``).
TREE = "tree"
#: ASPRS classes: processed but not assigned, and ground.
UNASSIGNED, GROUND = 1, 2

#: Each point's tree (its number from 1, 0 for none) and whether it is ground, from
#: an (M, 3) chunk of points in the frame of the file being written.
PointLabels = Callable[[np.ndarray], tuple[np.ndarray, np.ndarray]]
#: How far beyond a sample's box the points it was drawn from may reach (m).
SAMPLE_MARGIN_M = 1.0


#: The extra-bytes record (192 bytes per attribute) must fit one VLR of 65,535 bytes.
MAX_EXTRA_DIMS = 65535 // 192


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


def _frame(
    box: tuple[np.ndarray, np.ndarray] | None,
    offset: np.ndarray,
    meta: Mapping[str, Any],
) -> tuple[np.ndarray, np.ndarray]:
    """Return the header's scales and offsets for points in ``box`` + ``offset``.

    0.1 mm (or the file's finer scale), coarsened only where 32-bit integers could
    not span the points.
    """
    scales = np.minimum(
        np.asarray(meta.get("las_scales", [_DEFAULT_SCALE_M] * 3), float),
        _DEFAULT_SCALE_M,
    )
    offsets = np.round(offset)
    if box is None:
        return scales, offsets
    lo, hi = box
    if np.any(
        np.maximum(abs(lo), abs(hi)) + abs(offset - offsets) > _INT32_MAX * scales
    ):
        offsets = np.round(offset + (lo + hi) / 2)  # re-centre on the points
    reach = np.maximum(abs(lo + offset - offsets), abs(hi + offset - offsets))
    too_fine = reach > 0.99 * _INT32_MAX * scales
    if too_fine.any():
        coarse = 10.0 ** np.ceil(np.log10(reach / (0.99 * _INT32_MAX)))
        scales = np.where(too_fine, coarse, scales)
        logger.warning(
            "The cloud spans %s m; LAS scale coarsened to %s m to fit 32-bit integers.",
            np.round(hi - lo).tolist(),
            scales.tolist(),
        )
    return scales, offsets


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


def write_las(
    path: Path, cloud: Cloud, *, binary: bool = True, compress: bool = False
) -> None:
    """Write LAS (or LAZ when ``compress``) keeping every attribute; see module docs."""
    write_las_parts(path, [cloud], [np.eye(4)], cloud.offset, None, compress=compress)


def write_las_parts(
    path: Path,
    parts: Sequence[Cloud],
    moves: Sequence[Transform],
    offset: np.ndarray,
    ids: Sequence[int] | None,
    *,
    compress: bool = True,
    load: Callable[[int], Cloud] | None = None,
    labels: PointLabels | None = None,
) -> None:
    """Write clouds moved into one frame as one LAS (LAZ when ``compress``) file.

    ``moves[k]`` takes ``parts[k]``'s local coordinates into the frame whose origin
    is ``offset`` (world coordinates); with ``ids``, every point of part k gets
    ``scan_id`` = ``ids[k]``, and ``point_source_id`` too where the parts carry none
    (the field LAS tools sort merged scans by). The attributes every part has are kept; the first
    part's LAS version and VLRs (e.g. its coordinate system) are the file's. No more
    than ``CHUNK_POINTS`` points are moved at a time. With ``load``, the points
    written for part k are ``load(k)``'s and ``parts`` are samples of them, which
    plan the attributes and the extent: a value the sample did not show that a
    standard field cannot hold is written clipped, with a warning. With ``labels``
    of its coordinates in the frame (local to ``offset``), every point gets ``tree``,
    and a point the scan left unclassified (class 0 or 1) class 2 where it is ground,
    1 elsewhere; the classes a scan set are kept.
    """
    import laspy

    offset = np.asarray(offset, float)
    every = [set(flat_attributes(c)) for c in parts]
    names = set.intersection(*every) if every else set()
    if ids is not None:
        names.discard("scan_id")
    if labels is not None:
        names.discard(TREE)
    meta = parts[0].meta if parts else {}
    point_format = _choose_format(names, meta)
    standard, extra = _plan(parts, names, point_format)
    source_ids = ids is not None and "point_source_id" not in standard
    version = "1.4" if meta.get("las_version") == "1.4" else None
    header = laspy.LasHeader(point_format=point_format, version=version)
    box = _moved_box(parts, moves)
    if box is not None and load is not None:  # a sample's extent, not every point's
        box = (box[0] - SAMPLE_MARGIN_M, box[1] + SAMPLE_MARGIN_M)
    header.scales, header.offsets = _frame(box, offset, meta)
    dims = {k: dt for k, (_, dt) in extra.items()}
    if ids is not None:
        dims["scan_id"] = np.dtype(np.uint16)
    if labels is not None:
        dims[TREE] = np.dtype(np.uint32)
    header.add_extra_dims(
        [laspy.ExtraBytesParams(name, dtype.str[1:]) for name, dtype in dims.items()]
    )
    for user_id, record_id, description, data in meta.get("las_vlrs", ()):
        header.vlrs.append(laspy.VLR(user_id, record_id, description, data))
    fmt = laspy.PointFormat(point_format)
    with (
        _ctrl_c_between_chunks() as check,
        laspy.open(path, mode="w", header=header, do_compress=compress) as writer,
    ):
        for k, (part, T) in enumerate(zip(parts, moves, strict=True)):
            cloud = part if load is None else load(k)
            attrs = flat_attributes(cloud)
            R, t = np.asarray(T, float)[:3, :3], np.asarray(T, float)[:3, 3]
            for lo in range(0, len(cloud), CHUNK_POINTS):
                rows = slice(lo, lo + CHUNK_POINTS)
                moved = cloud.xyz[rows] @ R.T + t
                xyz = moved + (offset - header.offsets)
                record = laspy.ScaleAwarePointRecord.zeros(len(xyz), header=header)
                ints = np.round(xyz / header.scales).astype(np.int32)
                record.X, record.Y, record.Z = ints[:, 0], ints[:, 1], ints[:, 2]
                if ids is not None:
                    record["scan_id"] = np.full(len(xyz), ids[k], np.uint16)
                if source_ids:
                    record["point_source_id"] = record["scan_id"]
                _put_attributes(record, fmt, standard, extra, attrs, rows)
                if labels is not None:
                    _put_labels(record, *labels(moved))
                writer.write_points(record)
                check()


def _put_labels(record: Any, tree: np.ndarray, ground: np.ndarray) -> None:
    """Set each point's tree, and class 2 or 1 where the scan left it unclassified.

    A scan's classes a 5-bit field cannot hold went to an exact extra field as well,
    which readers prefer (``_plan``): it gets the same classes.
    """
    record[TREE] = np.asarray(tree, np.uint32)
    exact = PREFIX + "classification"
    names = set(record.point_format.dimension_names)
    for field in ("classification", *([exact] if exact in names else [])):
        given = np.asarray(record[field])
        unset = given <= UNASSIGNED
        record[field] = np.where(
            unset, np.where(ground, GROUND, UNASSIGNED), given
        ).astype(given.dtype)


def _put_attributes(
    record: Any,
    fmt: Any,
    standard: set[str],
    extra: Mapping[str, tuple[str, np.dtype[Any]]],
    attrs: Mapping[str, np.ndarray],
    rows: slice,
) -> None:
    """Fill ``record`` with the attributes' ``rows``: standard fields, then extra ones."""
    for name in standard:
        dim = fmt.dimension_by_name(name)
        record[name], exact = _fit(dim, attrs[name][rows])
        if not exact and PREFIX + name not in extra:
            logger.warning(
                "%s: values the LAS field cannot hold, written clipped.", name
            )
    for key, (name, dtype) in extra.items():
        record[key] = np.asarray(attrs[name][rows], dtype)


@contextlib.contextmanager
def _ctrl_c_between_chunks() -> Iterator[Callable[[], None]]:
    """Hold Ctrl+C inside the block; ``check()`` and the block's end raise it.

    lazrs writes through a Python callback, and a KeyboardInterrupt raised in that
    callback comes out as a write error; held, it stops the write as Ctrl+C. Only the
    main thread with Python's own handler holds it (no other thread gets signals).
    """
    pending: list[int] = []

    def check() -> None:
        if pending:
            raise KeyboardInterrupt

    own = threading.current_thread() is threading.main_thread()
    if not own or signal.getsignal(signal.SIGINT) is not signal.default_int_handler:
        yield lambda: None
        return
    signal.signal(signal.SIGINT, lambda signum, _frame: pending.append(signum))
    try:
        yield check
    except Exception as exc:
        if pending:  # the write failed after a Ctrl+C: the Ctrl+C is what to report
            raise KeyboardInterrupt from exc
        raise
    finally:
        signal.signal(signal.SIGINT, signal.default_int_handler)
    check()


def _plan(
    parts: Sequence[Cloud], names: set[str], point_format: int
) -> tuple[set[str], dict[str, tuple[str, np.dtype[Any]]]]:
    """Which attributes go into standard dimensions, and the extra ones.

    A standard-named attribute fills its field; when the field cannot hold its
    values exactly (in any part), they are also kept in ``amrst_<name>``. Returns
    the standard names and ``{extra dimension: (attribute, dtype)}``.
    """
    import laspy

    fmt = laspy.PointFormat(point_format)
    standard: set[str] = set()
    extra: dict[str, tuple[str, np.dtype[Any]]] = {}
    for name in sorted(names):
        columns = [flat_attributes(c)[name] for c in parts]
        key = name
        if name in dimension_names(point_format):
            standard.add(name)
            dim = fmt.dimension_by_name(name)
            if all(_fit(dim, v)[1] for v in columns):
                continue
            key = PREFIX + name
        kept = [storable(v, allow_int64=True, name=name) for v in columns]
        if all(v is not None for v in kept):
            if len(key) > 32:
                logger.warning("LAS extra dimension name %r cut to 32 characters.", key)
            dtype = np.result_type(*(v.dtype for v in kept if v is not None))
            extra[key[:32]] = (name, dtype)
    if len(extra) > MAX_EXTRA_DIMS:
        dropped = sorted(extra)[MAX_EXTRA_DIMS:]
        logger.warning(
            "LAS holds %d extra attributes at most: %d not written (%s, ...); write "
            "PLY or PCD to keep them all.",
            MAX_EXTRA_DIMS,
            len(dropped),
            dropped[0],
        )
        extra = {k: extra[k] for k in sorted(extra)[:MAX_EXTRA_DIMS]}
    return standard, extra


def _moved_box(
    parts: Sequence[Cloud], moves: Sequence[Transform]
) -> tuple[np.ndarray, np.ndarray] | None:
    """Low and high corners of the parts' bounding boxes, moved."""
    corners = []
    for cloud, T in zip(parts, moves, strict=True):
        if not len(cloud):
            continue
        lo, hi = cloud.xyz.min(axis=0), cloud.xyz.max(axis=0)
        box = np.array(
            [
                [x, y, z]
                for x in (lo[0], hi[0])
                for y in (lo[1], hi[1])
                for z in (lo[2], hi[2])
            ]
        )
        corners.append(box @ np.asarray(T)[:3, :3].T + np.asarray(T)[:3, 3])
    if not corners:
        return None
    every = np.vstack(corners)
    return every.min(axis=0), every.max(axis=0)
