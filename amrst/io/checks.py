"""The checks of the scans a command is given, before any registration sees them.

The same points given twice, coordinates not in metres or in coarse steps, stray rows
kilometres off the rest: each reads without error and registers to nothing, so each is
refused with a one-line :class:`~amrst.errors.InvalidInput` that says what to change.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from amrst.errors import InvalidInput
from amrst.sampling import strided

if TYPE_CHECKING:
    from collections.abc import Sequence

    from amrst.types import Cloud


#: Two scans whose points lie this close (m) are one scan written twice: LAS stores
#: millimetres, text often micrometres.
SAME_POINT_M = 0.002
#: Points of one scan looked up in the other to tell.
SAME_SAMPLE = 2000


def _box(cloud: Cloud) -> np.ndarray:
    """(3, 3) a cloud's world min, max and mean: what tells two scans apart at once."""
    stats = [f(cloud.xyz, axis=0) for f in (np.min, np.max, np.mean)]
    box: np.ndarray = np.asarray(stats, dtype=np.float64) + cloud.offset
    return box


def _same_points(a: Cloud, b: Cloud, tol_m: float) -> bool:
    """Tell whether two clouds of the same size and box hold the same points."""
    if np.array_equal(a.offset, b.offset) and np.array_equal(a.xyz, b.xyz):
        return True
    from scipy.spatial import cKDTree  # imported when needed: every command checks

    bxyz = strided(b.xyz, SAME_SAMPLE) + (b.offset - a.offset)
    dist, _ = cKDTree(a.xyz).query(bxyz, distance_upper_bound=tol_m)
    return bool(np.mean(np.isfinite(dist)) > 0.99)


def refuse_same_points(
    clouds: Sequence[Cloud], labels: Sequence[str], tol_m: float = SAME_POINT_M
) -> None:
    """Refuse two scans holding the same points, in any order and precision.

    One file given twice, a copy, the same scan exported again as text or LAS (rows
    in another order, coordinates rounded). Registering a scan onto itself tells
    nothing and the verification of the identity runs long on a big scan. Scans of
    different positions differ in size or box at once; only clouds that agree in
    both are compared point by point. ``tol_m``: how far apart the same point may
    read (clouds thinned on a voxel grid: the voxel; a rounded copy may pick
    another point of a voxel).
    """
    boxes: dict[int, np.ndarray] = {}  # each cloud's, once, when a size matches
    for j, b in enumerate(clouds):
        for i, a in enumerate(clouds[:j]):
            if not len(a) or abs(len(a) - len(b)) > 0.01 * max(len(a), len(b)):
                continue
            for k in (i, j):
                if k not in boxes:
                    boxes[k] = _box(clouds[k])
            close = np.allclose(boxes[i], boxes[j], rtol=0.0, atol=tol_m)
            if close and _same_points(a, b, tol_m):
                what = (
                    "is given twice (a file of several scans gives them all)"
                    if labels[j] == labels[i]
                    else f"holds the same points as {labels[i]}"
                )
                raise InvalidInput(f"{labels[j]} {what}: give each scan once.")


#: A scan in metres spans less than this from its lowest points to its highest (m);
#: one in millimetres or centimetres spans far more.
MAX_HEIGHT_SPAN_M = 1000.0
#: Coordinates in steps this coarse (m) hold no stem to find or measure.
MAX_STEP_M = 0.1
#: Points the coordinate checks look at (every k-th of a scan's rows).
CHECK_POINTS = 200_000
#: No laser scanner reaches this far (m): a point this far beyond the bulk of its scan
#: is a stray row of a bad export.
STRAY_M = 10_000.0


def _refuse_strays(cloud: Cloud, sample: np.ndarray, label: str) -> None:
    """Refuse a scan with points over ``STRAY_M`` beyond the box of its bulk.

    They would stretch every output: a LAS file of the plot keeps metres, not
    millimetres, when its points span thousands of kilometres.
    """
    bulk_lo, bulk_hi = np.percentile(sample, [0.1, 99.9], axis=0)
    lo = np.array([cloud.xyz[:, k].min() for k in range(3)])
    hi = np.array([cloud.xyz[:, k].max() for k in range(3)])
    if (lo >= bulk_lo - STRAY_M).all() and (hi <= bulk_hi + STRAY_M).all():
        return
    far = np.zeros(len(cloud), dtype=bool)
    for k in range(3):
        far |= cloud.xyz[:, k] < bulk_lo[k] - STRAY_M
        far |= cloud.xyz[:, k] > bulk_hi[k] + STRAY_M
    worst = float(np.abs(cloud.xyz[far] - (bulk_lo + bulk_hi) / 2).max())
    raise InvalidInput(
        f"{label}: {int(far.sum()):,} point(s) lie up to {worst:.3g} m from the rest "
        f"of the scan, over {STRAY_M / 1000:g} km, farther than a scanner sees: stray "
        "rows of a bad export. Remove them (amrst clip keeps a cylinder) or export "
        "the scan again."
    )


def refuse_odd_coordinates(cloud: Cloud, label: str) -> None:
    """Refuse a scan whose coordinates are not in metres, or come in coarse steps.

    Both read without error and register to nothing: the defaults measure in metres,
    and points snapped to a half-metre grid (float32 far from the origin) show no
    stem: their values repeat, where those of a sparse scan do not. Stray points
    kilometres off the rest are refused too (:func:`_refuse_strays`). Scans of under a
    thousand points are left to the checks that count points.
    """
    if len(cloud) < 1000:
        return
    xyz = strided(cloud.xyz, CHECK_POINTS)  # finite: a Cloud's are
    _refuse_strays(cloud, xyz, label)
    lo, hi = np.percentile(xyz[:, 2], [0.5, 99.5])
    if hi - lo > MAX_HEIGHT_SPAN_M:
        raise InvalidInput(
            f"{label} spans {hi - lo:,.0f} m from its lowest points to its highest: "
            "are its coordinates in millimetres or centimetres? Give the scan in "
            "metres."
        )
    for axis, name in enumerate("xyz"):
        values = np.unique(xyz[:, axis])
        if len(values) * 10 > len(xyz):
            continue  # a value repeats less than ten times: sparse, not snapped
        step = float(np.percentile(np.diff(values), 10)) if len(values) > 1 else 0.0
        if step >= MAX_STEP_M:
            raise InvalidInput(
                f"{label}'s {name} coordinates come in steps of {100 * step:.0f} cm: "
                "are they whole millimetres or centimetres, or did the file keep too "
                "few digits (float32 far from the origin)? Give the scan in metres, "
                "with double-precision coordinates or as LAS/LAZ, whose offset keeps "
                "them."
            )


def check_scans(clouds: Sequence[Cloud], labels: Sequence[str]) -> None:
    """Refuse scans no registration can use.

    The same points given twice (:func:`refuse_same_points`), or coordinates not in
    metres or in coarse steps (:func:`refuse_odd_coordinates`).
    """
    refuse_same_points(clouds, labels)
    for cloud, label in zip(clouds, labels, strict=True):
        refuse_odd_coordinates(cloud, label)
