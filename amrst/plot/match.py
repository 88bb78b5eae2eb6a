"""Candidate poses of a plot pair from its two stem maps.

Stems are key points with an attribute: their breast-height centre on the ground, and
their DBH. Every pair of stems in one scan is compared with every pair in the other
(same length, DBH alike); two stems fix a levelled pose (heading and shift), which the
other stems then confirm or not. Poses confirmed by three stems or more are the
similar triangles of stem bases; poses with two stems only are kept too (a position
that sees only two of the shared trees), ranked after them. The scanners' residual
tilt is taken out by laying one scan's ground on the other's under the pose (by
their ground normals where they share too little ground).
The poses go through the same verification as every other candidate (``verify.py``).
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import TYPE_CHECKING

import numpy as np

from amrst.geometry import rotvec_matrix
from amrst.review.manual import fit_levelled
from amrst.stages.candidates import distinct_solutions

if TYPE_CHECKING:
    from amrst.plot.stemmap import StemMap
    from amrst.types import Transform

#: Two stem pairs match when their lengths differ by less than this plus LENGTH_REL.
LENGTH_TOL_M = 0.15
LENGTH_REL = 0.02
#: A moved source stem confirms a pose within this of a target stem (m, horizontal).
CONFIRM_M = 0.35
#: Shortest stem pair that fixes a heading (m).
MIN_PAIR_M = 1.5
#: A pose the point score cannot judge is held by its stems alone when at least this
#: many meet within HELD_RMS_M and no other pose is confirmed by as many.
HELD_STEMS = 4
HELD_RMS_M = 0.1
#: A stem's key point is where its circles put it to within KEY_SD_M plus
#: KEY_SD_SHARE of its diameter (a wide stem's section is seldom round, and each scan
#: sees another side of it), or NO_DBH_SD_M where either scan has no circle for it;
#: the pose's fit weighs each stem pair by the inverse square.
KEY_SD_M = 0.01
KEY_SD_SHARE = 0.1
NO_DBH_SD_M = 0.1
#: A pose held by its stems alone needs review when they fix its heading no better
#: than this (1 sd, degrees; 7 cm at 10 m).
HELD_HEADING_SD_DEG = 0.4
#: A pose is levelled on the ground both scans see when they share this many cells
#: of it (50 m2 of 0.5 m cells); cells more than LEVEL_TRIM_M off the fit are left out.
SHARED_GROUND_CELLS = 200
LEVEL_TRIM_M = 0.2


@dataclass(frozen=True, slots=True)
class StemPose:
    """One candidate pose: ``T_target_source`` and the stems that confirm it."""

    T_target_source: Transform
    pairs: np.ndarray  # (K, 2) target stem, source stem
    rms_m: float  # horizontal RMS of the confirming stems
    dbh_agree: int  # confirming stems whose DBH agree (both measured)
    heading_sd_deg: float = 0.0  # how well the stems fix the heading (key_weights)


def dbh_alike(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Tell whether DBHs agree (unknown ones agree with anything).

    A single scan sees half a stem, so its DBH is rough: alike within 5 cm + 30 %.
    """
    both = np.isfinite(a) & np.isfinite(b)
    close = np.abs(a - b) <= 0.05 + 0.3 * np.fmax(a, b)
    return np.asarray(~both | close)


def key_weights(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """(K,) weights of stem pairs of DBHs ``a`` and ``b`` in a pose's fit."""
    sd = np.where(
        np.isfinite(a) & np.isfinite(b),
        KEY_SD_M + KEY_SD_SHARE * np.fmax(a, b),
        NO_DBH_SD_M,
    )
    return np.asarray(1.0 / sd**2)


def _segments(keys: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    i, j = np.triu_indices(len(keys), k=1)
    length = np.hypot(*(keys[j, :2] - keys[i, :2]).T)
    keep = length >= MIN_PAIR_M
    return np.column_stack([i[keep], j[keep]]), length[keep]


def _tilt_fix(
    T: Transform, n_target: np.ndarray, n_source: np.ndarray, pivot: np.ndarray
) -> Transform:
    """Turn the pose so the moved source's ground normal meets the target's.

    The turn is about ``pivot`` (the target's stems), not the frame's origin: a scan
    in coordinates a kilometre from their origin would be moved metres by a tenth of
    a degree.
    """
    moved = T[:3, :3] @ n_source
    axis = np.cross(moved, n_target)
    s = float(np.linalg.norm(axis))
    if s < 1e-9:
        return T
    angle = np.arcsin(min(s, 1.0))
    R = rotvec_matrix(axis / s * angle)
    out = np.eye(4)
    out[:3, :3] = R @ T[:3, :3]
    out[:3, 3] = R @ (T[:3, 3] - pivot) + pivot
    return out


def _confirm(
    T: Transform, tk: np.ndarray, sk: np.ndarray, td: np.ndarray, sd: np.ndarray
) -> np.ndarray:
    """(K, 2) target/source stems that agree under T (nearest, each target once)."""
    moved = sk @ T[:3, :3].T + T[:3, 3]
    d = np.hypot(moved[:, None, 0] - tk[None, :, 0], moved[:, None, 1] - tk[None, :, 1])
    best = np.argmin(d, axis=1)
    ok = (d[np.arange(len(sk)), best] <= CONFIRM_M) & dbh_alike(td[best], sd)
    pairs = [(int(best[s]), s) for s in np.flatnonzero(ok)]
    seen: set[int] = set()
    unique = []
    for t, s in sorted(pairs, key=lambda p: d[p[1], p[0]]):
        if t not in seen:
            seen.add(t)
            unique.append((t, s))
    return np.array(sorted(unique), dtype=np.int64).reshape(-1, 2)


def stem_poses(target: StemMap, source: StemMap, max_poses: int = 6) -> list[StemPose]:
    """Candidate poses of ``source`` on ``target`` from their stems, best first.

    Parameters
    ----------
    target, source : StemMap
        Each scan's stem map (its local frame).
    max_poses : int
        Distinct poses returned at most.

    Returns
    -------
    list of StemPose
        Most confirming stems first, then smallest RMS; empty when either scan has
        fewer than two stems.
    """
    tk, sk = target.keys(), source.keys()
    td, sd = target.dbh(), source.dbh()
    if len(tk) < 2 or len(sk) < 2:
        return []
    tseg, tlen = _segments(tk)
    sseg, slen = _segments(sk)
    if not len(tseg) or not len(sseg):
        return []
    close = np.abs(tlen[:, None] - slen[None, :]) <= LENGTH_TOL_M + LENGTH_REL * (
        np.fmax(tlen[:, None], slen[None, :])
    )
    poses: list[StemPose] = []
    tried: set[tuple[tuple[int, int], ...]] = set()
    nt, ns = target.ground.normal, source.ground.normal
    for a, b in zip(*np.nonzero(close), strict=True):
        for flip in (False, True):
            t2 = tseg[a]
            s2 = sseg[b][::-1] if flip else sseg[b]
            if not dbh_alike(td[t2], sd[s2]).all():
                continue
            T = _tilt_fix(fit_levelled(tk[t2], sk[s2]), nt, ns, tk[t2].mean(axis=0))
            pairs = _confirm(T, tk, sk, td, sd)
            key = tuple(map(tuple, pairs.tolist()))
            if len(pairs) < 2 or key in tried:
                continue
            tried.add(key)
            poses.append(_refit(pairs, tk, sk, td, sd, normals=(nt, ns)))
    poses.sort(key=lambda p: (-len(p.pairs), -p.dbh_agree, p.rms_m))
    out: list[StemPose] = []
    centre = sk.mean(axis=0)
    for p in poses:
        if all(
            distinct_solutions(p.T_target_source, q.T_target_source, centre)
            for q in out
        ):
            out.append(p)
        if len(out) == max_poses:
            break
    return [_levelled_on_ground(p, target, source) for p in out]


def _levelled_on_ground(pose: StemPose, target: StemMap, source: StemMap) -> StemPose:
    """Take the pose's residual tilt from the ground both scans see under it.

    The ground normals agree only where both scans see the same plane; over a terrain
    that bends, each scan's plane leans its own way. So the source's ground, moved by
    the stems' levelled pose, is laid on the target's: the plane of their height
    differences (cells more than ``LEVEL_TRIM_M`` off it left out: a shrub one scan
    sees round) is the tilt and the height left. The pose is kept as it is when the
    scans share fewer than ``SHARED_GROUND_CELLS`` ground cells.
    """
    from scipy.spatial import cKDTree

    tg, sg = target.ground, source.ground
    if not (tg.found and sg.found):
        return pose
    t = target.keys()[pose.pairs[:, 0]]
    s = source.keys()[pose.pairs[:, 1]]
    w = key_weights(target.dbh()[pose.pairs[:, 0]], source.dbh()[pose.pairs[:, 1]])
    T = fit_levelled(t, s, w)
    cells = np.c_[sg.centres, sg.surface_z(sg.centres)] @ T[:3, :3].T + T[:3, 3]
    gap = cKDTree(tg.centres).query(cells[:, :2], distance_upper_bound=tg.cell_m)[0]
    cells = cells[np.isfinite(gap)]
    if len(cells) < SHARED_GROUND_CELLS:
        return pose
    pivot = (w / w.sum()) @ t
    A = np.c_[cells[:, :2] - pivot[:2], np.ones(len(cells))]
    dz = cells[:, 2] - tg.surface_z(cells[:, :2])
    on = np.ones(len(cells), dtype=bool)
    for _ in range(3):
        coef = np.linalg.lstsq(A[on], dz[on], rcond=None)[0]
        on = np.abs(dz - A @ coef) <= LEVEL_TRIM_M
        if on.sum() < SHARED_GROUND_CELLS:
            return pose
    a, b, c = np.linalg.lstsq(A[on], dz[on], rcond=None)[0]
    tilted = np.array([-a, -b, 1.0]) / np.hypot(np.hypot(a, b), 1.0)
    T = _tilt_fix(T, np.array([0.0, 0.0, 1.0]), T[:3, :3].T @ tilted, pivot)
    T[2, 3] -= c
    return replace(pose, T_target_source=T, rms_m=_horizontal_rms(T, t, s))


def _horizontal_rms(T: Transform, t: np.ndarray, s: np.ndarray) -> float:
    """Return how far apart the stems ``t`` and ``s`` moved by ``T`` stand (RMS, m)."""
    moved = s @ T[:3, :3].T + T[:3, 3]
    return float(np.sqrt(np.mean(np.sum((moved[:, :2] - t[:, :2]) ** 2, axis=1))))


def held_by_stems(poses: list[StemPose]) -> int | None:
    """Return the index of the pose its stems alone verify, or None.

    Scans of a plot taken far apart share too little surface for the share of points
    that meet (the verification score) to tell a right pose from a wrong one; the
    stems still can: four or more stems that meet within 10 cm after the fit make a
    pose, and a pattern that repeats would give another pose as many stems.
    ``poses`` as :func:`stem_poses` returns them (most confirming stems first).
    """
    if not poses:
        return None
    best = poses[0]
    rival = len(poses[1].pairs) if len(poses) > 1 else 0
    held = (
        len(best.pairs) >= HELD_STEMS
        and best.rms_m <= HELD_RMS_M
        and rival < len(best.pairs)
    )
    return 0 if held else None


def _refit(
    pairs: np.ndarray,
    tk: np.ndarray,
    sk: np.ndarray,
    td: np.ndarray,
    sd: np.ndarray,
    *,
    normals: tuple[np.ndarray, np.ndarray],
) -> StemPose:
    """Levelled fit on every confirming stem, tilt taken out, and its figures."""
    t, s = tk[pairs[:, 0]], sk[pairs[:, 1]]
    a, b = td[pairs[:, 0]], sd[pairs[:, 1]]
    weights = key_weights(a, b)
    w = weights / weights.sum()
    T = _tilt_fix(fit_levelled(t, s, w), *normals, w @ t)
    T[:3, 3] += w @ (t - (s @ T[:3, :3].T + T[:3, 3]))
    agree = int(np.sum(np.isfinite(a) & np.isfinite(b) & dbh_alike(a, b)))
    sd_deg = _heading_sd_deg(t, weights)
    return StemPose(T, pairs, _horizontal_rms(T, t, s), agree, sd_deg)


def _heading_sd_deg(t: np.ndarray, weights: np.ndarray) -> float:
    """Return how well stems ``t`` of :func:`key_weights` ``weights`` fix a heading.

    The sd (degrees) of a levelled fit's heading when each stem's key point is off by
    its own sd: 1 / sqrt(sum of weight x squared distance from the weighted centre).
    """
    centre = (weights / weights.sum()) @ t[:, :2]
    spread = float(np.sum(weights * np.sum((t[:, :2] - centre) ** 2, axis=1)))
    return float(np.degrees(1.0 / np.sqrt(spread))) if spread > 0 else 180.0
