"""The stem at breast height: a circle fitted to the bark points of a slice.

RANSAC on three-point circles (branches and leaves in the slice do not pull it), then a
geometric least-squares fit on the inliers; ``arc_deg`` is how much of the
circumference the inliers cover. Bark points are told from needles and twigs by their
upright, flat neighbourhoods (:func:`stem_surface`). Used by amrst.measure.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    from amrst.measure import MeasureParams

# A stem circle needs this many inlier points, spread over at least this arc.
_MIN_STEM_POINTS = 12
_MIN_ARC_DEG = 60.0
_ARC_CANDIDATES = 40
_REFINE_ITERATIONS = 30
# Stem surface: neighbours for the normals, extra band (m), largest |normal z|, and
# largest curvature (smallest eigenvalue over their sum) of a bark neighbourhood.
_SURFACE_NEIGHBOURS = 12
_SURFACE_BAND_M = 0.1
_MAX_NORMAL_Z = 0.4
_MAX_CURVATURE = 0.06


@dataclass(frozen=True, slots=True)
class StemCircle:
    """The stem cross-section at breast height."""

    centre_xy: tuple[float, float]  # world x, y (m)
    radius_m: float
    rmse_m: float  # RMS distance of the inliers from the circle
    n_points: int  # inliers
    arc_deg: float  # share of the circumference the inliers cover, in degrees


def _circles(p: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Circumcircles of (S, 3, 2) point triples: centres (S, 2), radii (S,)."""
    a, b, c = p[:, 0], p[:, 1], p[:, 2]
    d = 2 * (
        a[:, 0] * (b[:, 1] - c[:, 1])
        + b[:, 0] * (c[:, 1] - a[:, 1])
        + c[:, 0] * (a[:, 1] - b[:, 1])
    )
    sa, sb, sc = (np.sum(q * q, axis=1) for q in (a, b, c))
    with np.errstate(divide="ignore", invalid="ignore"):
        ux = (
            sa * (b[:, 1] - c[:, 1])
            + sb * (c[:, 1] - a[:, 1])
            + sc * (a[:, 1] - b[:, 1])
        ) / d
        uy = (
            sa * (c[:, 0] - b[:, 0])
            + sb * (a[:, 0] - c[:, 0])
            + sc * (b[:, 0] - a[:, 0])
        ) / d
    centres = np.column_stack([ux, uy])
    return centres, np.linalg.norm(a - centres, axis=1)


def _refine_circle(
    xy: np.ndarray,
    centre: np.ndarray,
    radius: float,
    scale: float,
    *,
    fit_radius: bool = True,
) -> tuple[np.ndarray, float]:
    """Geometric circle fit (distances to the circle), Gauss-Newton with soft-L1 weights.

    What scipy.optimize.least_squares(loss="soft_l1") does, in a few lines: importing
    scipy.optimize alone is a noticeable share of a short command.
    ``fit_radius=False`` keeps the radius and fits the centre alone.
    """
    v = np.r_[centre, radius].astype(np.float64)
    n = 3 if fit_radius else 2
    for _ in range(_REFINE_ITERATIONS):
        d = xy - v[:2]
        dist = np.maximum(np.linalg.norm(d, axis=1), 1e-12)
        r = dist - v[2]
        w = 1.0 / np.sqrt(1.0 + (r / scale) ** 2)  # soft-L1 (IRLS weights)
        J = np.column_stack([-d[:, 0] / dist, -d[:, 1] / dist, -np.ones(len(r))])[:, :n]
        step = np.linalg.lstsq(J * w[:, None], -r * w, rcond=None)[0]
        v[:n] += step
        if np.abs(step).max() < 1e-7:
            break
    return v[:2], float(abs(v[2]))


def centre_at_radius(
    xy: np.ndarray, centre: np.ndarray, radius: float, scale: float
) -> np.ndarray:
    """(2,) centre of the circle of ``radius`` that fits ``xy`` (soft-L1, ``scale`` m)."""
    return _refine_circle(xy, centre, radius, scale, fit_radius=False)[0]


def arc_deg(xy: np.ndarray, centre: np.ndarray) -> float:
    """Degrees of the circumference around ``centre`` that ``xy`` covers.

    360 minus the largest gap between neighbouring points' angles.
    """
    angles = np.sort(np.arctan2(xy[:, 1] - centre[1], xy[:, 0] - centre[0]))
    gaps = np.diff(np.r_[angles, angles[0] + 2 * np.pi])
    return float(np.degrees(2 * np.pi - gaps.max()))


def _arcs_deg(
    xy: np.ndarray, centres: np.ndarray, radii: np.ndarray, inlier_m: float
) -> np.ndarray:
    """:func:`arc_deg` of each circle's inliers among ``xy``, for all circles at once.

    Every circle has at least two inliers.
    """
    d = xy[None] - centres[:, None]  # (C, N, 2)
    inl = np.abs(np.linalg.norm(d, axis=2) - radii[:, None]) <= inlier_m
    angles = np.where(inl, np.arctan2(d[..., 1], d[..., 0]), np.inf)
    angles.sort(axis=1)  # each circle's inliers first, in order
    last = angles[np.arange(len(angles)), inl.sum(axis=1) - 1]
    with np.errstate(invalid="ignore"):  # inf - inf past the inliers
        gaps = np.diff(angles, axis=1)
    gaps[~np.isfinite(gaps)] = 0.0
    widest = np.maximum(gaps.max(axis=1), angles[:, 0] + 2 * np.pi - last)
    return np.asarray(np.degrees(2 * np.pi - widest))


def fit_stem_circle(xy: np.ndarray, params: MeasureParams) -> StemCircle | None:
    """Fit the stem circle to the (N, 2) points of a slice; None when there is none.

    Parameters
    ----------
    xy : (N, 2) float64
        Horizontal coordinates of the slice's points (m).
    params : MeasureParams

    Returns
    -------
    StemCircle or None
        None when fewer than 12 points lie on any circle, or they cover under 60 deg.
    """
    if len(xy) < _MIN_STEM_POINTS:
        return None
    origin = xy.mean(axis=0)
    pts = xy - origin
    rng = np.random.default_rng(params.seed)
    # Candidates are scored on at most this many points (a dense slice of a big scan
    # would cost memory, not accuracy); the final fit uses them all.
    few = pts if len(pts) <= 3000 else pts[rng.choice(len(pts), 3000, replace=False)]
    triples = rng.integers(0, len(few), size=(params.iterations, 3))
    triples = triples[
        (triples[:, 0] != triples[:, 1])
        & (triples[:, 1] != triples[:, 2])
        & (triples[:, 0] != triples[:, 2])
    ]
    centres, radii = _circles(few[triples])
    ok = np.isfinite(radii) & (radii > 0.005) & (radii <= params.max_radius_m)
    if not ok.any():
        return None
    centres, radii = centres[ok], radii[ok]
    # Inlier counts of every candidate, in chunks to bound the memory.
    counts = np.concatenate(
        [
            (
                np.abs(
                    np.linalg.norm(few[None] - centres[k : k + 256, None], axis=2)
                    - radii[k : k + 256, None]
                )
                <= params.inlier_m
            ).sum(axis=1)
            for k in range(0, len(radii), 256)
        ]
    )
    # The stem is the circle with many points all around it: of the best-supported
    # candidates, keep the one whose count times covered arc is largest (a big circle
    # through a buttress or branches touches many points over a short arc).
    top = np.argsort(-counts, kind="stable")[:_ARC_CANDIDATES]
    top = top[counts[top] >= min(_MIN_STEM_POINTS, len(few))]
    if not len(top):
        return None
    weight = counts[top] * _arcs_deg(few, centres[top], radii[top], params.inlier_m)
    best = int(top[int(np.argmax(weight))])
    centre, radius = centres[best], radii[best]
    inl = np.abs(np.linalg.norm(pts - centre, axis=1) - radius) <= params.inlier_m
    centre, radius = _refine_circle(pts[inl], centre, radius, params.inlier_m)
    resid = np.linalg.norm(pts - centre, axis=1) - radius
    inl = np.abs(resid) <= params.inlier_m
    if inl.sum() < _MIN_STEM_POINTS or radius > params.max_radius_m:
        return None
    arc = arc_deg(pts[inl], centre)
    if arc < _MIN_ARC_DEG:
        return None
    return StemCircle(
        (float(centre[0] + origin[0]), float(centre[1] + origin[1])),
        radius,
        float(np.sqrt(np.mean(resid[inl] ** 2))),
        int(inl.sum()),
        arc,
    )


def stem_surface(xyz: np.ndarray, z_centre: float, half: float) -> np.ndarray:
    """Points on a smooth, upright surface near ``z_centre`` (the stem's bark).

    Normals and curvature from the 12 nearest neighbours, computed in a band a little
    thicker than the slice so the neighbourhoods are whole. A stem point has a nearly
    horizontal normal and a flat neighbourhood; needles and twigs have neither.
    """
    from scipy.spatial import cKDTree

    out = np.zeros(len(xyz), dtype=bool)
    band = np.flatnonzero(np.abs(xyz[:, 2] - z_centre) <= half + _SURFACE_BAND_M)
    if len(band) < _SURFACE_NEIGHBOURS:
        return out
    pts = xyz[band]
    idx = cKDTree(pts).query(pts, _SURFACE_NEIGHBOURS)[1]
    nb = pts[idx] - pts[idx].mean(axis=1, keepdims=True)
    w, v = np.linalg.eigh(np.einsum("nki,nkj->nij", nb, nb))  # ascending
    upright = np.abs(v[:, 2, 0]) < _MAX_NORMAL_Z
    flat = w[:, 0] <= _MAX_CURVATURE * np.maximum(w.sum(axis=1), 1e-30)
    out[band] = upright & flat
    return out
