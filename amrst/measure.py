"""Tree measurements: height, stem diameter at breast height (DBH) and crown size.

Beyond the paper. Two scans are registered to measure one whole tree; a single TLS scan
sees only the half of the stem facing the scanner, so its DBH rests on a half circle.
:func:`measure_registration` measures the target, the moved source and the two merged,
so the report shows what the merge gained (the stem arc seen, in degrees).

- **Height**: top minus base, both taken on points that have neighbours (a stray point
  metres above the crown or below the base is not the tree).
- **DBH**: a circle fitted to the stem in a thin horizontal slice at breast height
  above the base: RANSAC on three-point circles (branches and leaves in the slice do
  not pull it), then a geometric least-squares fit on the inliers. ``arc_deg`` is how
  much of the circumference the inliers cover (360 minus the largest angular gap).
- **Crown**: the area of the convex hull of all points seen from above, and the crown
  width, the mean of its extents along the hull's two principal axes (the mean of two
  perpendicular crown widths that field crews measure).

The base is the lowest points: segment the tree and remove the ground first, as the
registration also assumes.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field
from typing import TYPE_CHECKING, Any

import numpy as np

from amrst.progress import NULL_REPORTER

if TYPE_CHECKING:
    from amrst.progress import Reporter
    from amrst.types import Cloud, Transform


@dataclass(frozen=True, slots=True, kw_only=True)
class MeasureParams:
    """Settings of the tree measurements."""

    breast_height_m: float = field(
        default=1.3,
        metadata={
            "unit": "m",
            "min": 0.1,
            "max": 10.0,
            "help": "Height above the tree's base at which the stem diameter (DBH) is measured (1.3 m in most countries, 1.37 m in the US).",
        },
    )
    slice_m: float = field(
        default=0.1,
        metadata={
            "unit": "m",
            "min": 0.01,
            "max": 1.0,
            "help": "Thickness of the horizontal slice the stem circle is fitted to.",
        },
    )
    inlier_m: float = field(
        default=0.01,
        metadata={
            "unit": "m",
            "min": 0.001,
            "max": 0.1,
            "help": "Largest distance of a stem point from the fitted circle (about twice the range noise).",
        },
    )
    max_radius_m: float = field(
        default=1.5,
        metadata={
            "unit": "m",
            "min": 0.05,
            "max": 10.0,
            "help": "Largest stem radius accepted.",
        },
    )
    iterations: int = field(
        default=500,
        metadata={
            "unit": "samples",
            "min": 10,
            "max": 100_000,
            "help": "Three-point circles tried by the RANSAC stem fit.",
        },
    )
    seed: int = field(
        default=0, metadata={"min": 0, "help": "Seed of the RANSAC sampling."}
    )


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
# Height: a point with fewer than this many others within _ISOLATION_M is a stray.
_ISOLATION_M = 0.3
_MIN_NEIGHBOURS = 2
_CROWN_GRID_M = 0.05
# Height over stem diameter of real trees stays above this (open-grown broadleaves and
# palms about 30-40, forest conifers 60-100).
_MIN_SLENDERNESS = 15.0


@dataclass(frozen=True, slots=True)
class StemCircle:
    """The stem cross-section at breast height."""

    centre_xy: tuple[float, float]  # world x, y (m)
    radius_m: float
    rmse_m: float  # RMS distance of the inliers from the circle
    n_points: int  # inliers
    arc_deg: float  # share of the circumference the inliers cover, in degrees


@dataclass(frozen=True, slots=True)
class TreeMeasures:
    """What a forester reads off one (merged) tree cloud."""

    n_points: int
    base_z: float  # world z of the base (m)
    height_m: float
    dbh_m: float  # NaN when no stem circle was found at breast height
    stem: StemCircle | None
    crown_area_m2: float
    crown_width_m: float
    note: str  # why DBH is missing, or ""

    def as_dict(self) -> dict[str, Any]:
        """Return plain numbers for JSON/CSV (stem fields flattened, NaN kept)."""
        out: dict[str, Any] = {
            "n_points": self.n_points,
            "height_m": self.height_m,
            "dbh_m": self.dbh_m,
            "crown_area_m2": self.crown_area_m2,
            "crown_width_m": self.crown_width_m,
            "base_z_m": self.base_z,
        }
        if self.stem is not None:
            stem = asdict(self.stem)
            out.update(
                stem_x_m=stem["centre_xy"][0],
                stem_y_m=stem["centre_xy"][1],
                stem_rmse_m=stem["rmse_m"],
                stem_points=stem["n_points"],
                stem_arc_deg=stem["arc_deg"],
            )
        if self.note:
            out["note"] = self.note
        return out

    def summary(self) -> str:
        """One line, e.g. ``height 11.9 m, DBH 31.4 cm (stem seen over 352 deg), ...``."""
        parts = [f"height {self.height_m:.2f} m"]
        if self.stem is not None:
            parts.append(
                f"DBH {100 * self.dbh_m:.1f} cm (stem seen over "
                f"{self.stem.arc_deg:.0f} deg)"
            )
        else:
            parts.append("DBH n/a")
        parts.append(
            f"crown {self.crown_width_m:.1f} m wide, {self.crown_area_m2:.1f} m2"
        )
        return ", ".join(parts)


def _kept(xyz: np.ndarray, candidates: np.ndarray) -> np.ndarray:
    """Of the candidate rows, the ones with neighbours (not isolated strays)."""
    from scipy.spatial import cKDTree

    # Only points near the candidates' heights can be their neighbours.
    z = xyz[candidates, 2]
    near = xyz[
        (xyz[:, 2] >= z.min() - _ISOLATION_M) & (xyz[:, 2] <= z.max() + _ISOLATION_M)
    ]
    counts = np.asarray(
        cKDTree(near).query_ball_point(
            xyz[candidates], _ISOLATION_M, return_length=True
        )
    )
    return candidates[counts > _MIN_NEIGHBOURS]  # counts include the point itself


def _base_and_top(xyz: np.ndarray) -> tuple[float, float]:
    z = xyz[:, 2]
    k = min(len(z), max(50, len(z) // 200))  # the lowest and highest 0.5 %
    order = np.argpartition(z, (k - 1, len(z) - k)) if len(z) > 2 * k else np.argsort(z)
    low = _kept(xyz, order[:k])
    high = _kept(xyz, order[-k:])
    base = float(z[low].min()) if len(low) else float(np.percentile(z, 0.5))
    top = float(z[high].max()) if len(high) else float(np.percentile(z, 99.5))
    return base, top


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
    xy: np.ndarray, centre: np.ndarray, radius: float, scale: float
) -> tuple[np.ndarray, float]:
    """Geometric circle fit (distances to the circle), Gauss-Newton with soft-L1 weights.

    What scipy.optimize.least_squares(loss="soft_l1") does, in a few lines: importing
    scipy.optimize alone costs 0.6 s per command.
    """
    v = np.r_[centre, radius].astype(np.float64)
    for _ in range(_REFINE_ITERATIONS):
        d = xy - v[:2]
        dist = np.maximum(np.linalg.norm(d, axis=1), 1e-12)
        r = dist - v[2]
        w = 1.0 / np.sqrt(1.0 + (r / scale) ** 2)  # soft-L1 (IRLS weights)
        J = np.column_stack([-d[:, 0] / dist, -d[:, 1] / dist, -np.ones(len(r))])
        step = np.linalg.lstsq(J * w[:, None], -r * w, rcond=None)[0]
        v += step
        if np.abs(step).max() < 1e-7:
            break
    return v[:2], float(abs(v[2]))


def _arc_deg(xy: np.ndarray, centre: np.ndarray) -> float:
    angles = np.sort(np.arctan2(xy[:, 1] - centre[1], xy[:, 0] - centre[0]))
    gaps = np.diff(np.r_[angles, angles[0] + 2 * np.pi])
    return float(np.degrees(2 * np.pi - gaps.max()))


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
    weight = [
        counts[j]
        * _arc_deg(
            few[
                np.abs(np.linalg.norm(few - centres[j], axis=1) - radii[j])
                <= params.inlier_m
            ],
            centres[j],
        )
        for j in top
    ]
    best = int(top[int(np.argmax(weight))])
    centre, radius = centres[best], radii[best]
    inl = np.abs(np.linalg.norm(pts - centre, axis=1) - radius) <= params.inlier_m
    centre, radius = _refine_circle(pts[inl], centre, radius, params.inlier_m)
    resid = np.linalg.norm(pts - centre, axis=1) - radius
    inl = np.abs(resid) <= params.inlier_m
    if inl.sum() < _MIN_STEM_POINTS or radius > params.max_radius_m:
        return None
    arc = _arc_deg(pts[inl], centre)
    if arc < _MIN_ARC_DEG:
        return None
    return StemCircle(
        (float(centre[0] + origin[0]), float(centre[1] + origin[1])),
        radius,
        float(np.sqrt(np.mean(resid[inl] ** 2))),
        int(inl.sum()),
        arc,
    )


def _stem_surface(xyz: np.ndarray, z_centre: float, half: float) -> np.ndarray:
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


def _crown(xy: np.ndarray) -> tuple[float, float]:
    """Convex-hull area (m2) and mean principal-axis width (m) of the points seen from above."""
    from scipy.spatial import ConvexHull, QhullError

    cells = np.unique(np.floor(xy / _CROWN_GRID_M).astype(np.int64), axis=0)
    pts = (cells + 0.5) * _CROWN_GRID_M
    if len(pts) < 3:
        return 0.0, 0.0
    try:
        hull = ConvexHull(pts)
    except QhullError:  # all on a line
        return 0.0, float(np.ptp(pts, axis=0).max())
    corners = pts[hull.vertices]
    axes = np.linalg.svd(pts - pts.mean(axis=0), full_matrices=False)[2]
    extents = np.ptp(corners @ axes.T, axis=0)
    return float(hull.volume), float(extents.mean())


def measure_tree(
    xyz: np.ndarray,
    params: MeasureParams | None = None,
    reporter: Reporter = NULL_REPORTER,
) -> TreeMeasures:
    """Measure one tree cloud.

    Parameters
    ----------
    xyz : (N, 3) float64
        World (or any common-frame) coordinates of one tree, z up (m).
    params : MeasureParams, optional

    Returns
    -------
    TreeMeasures
    """
    params = params or MeasureParams()
    xyz = np.asarray(xyz, dtype=np.float64)
    xyz = xyz[np.all(np.isfinite(xyz), axis=1)]
    if len(xyz) < 3:
        nan = float("nan")
        return TreeMeasures(len(xyz), nan, nan, nan, None, nan, nan, "too few points")
    base, top = _base_and_top(xyz)
    reporter.check_cancelled()  # between the parts: Cancel in the app (issue 15)
    z = xyz[:, 2]
    centre = base + params.breast_height_m
    in_slice = np.abs(z - centre) <= params.slice_m / 2
    # Only bark-like points: branches and needles crowd the slice of many conifers,
    # and a circle through them is no stem. No bark in view: no DBH (said in note).
    surface = _stem_surface(xyz, centre, params.slice_m / 2)
    reporter.check_cancelled()
    stem = fit_stem_circle(xyz[in_slice & surface, :2], params)
    note = ""
    height = top - base
    if stem is not None and height < _MIN_SLENDERNESS * 2 * stem.radius_m:
        # A conifer's crown envelope can look like bark to the surface test; no tree
        # is this thick for its height, so that circle is not the stem.
        note = (
            f"the only circle at {params.breast_height_m} m above the base "
            f"({200 * stem.radius_m:.0f} cm across) is too thick for a "
            f"{height:.1f} m tree (height/diameter under {_MIN_SLENDERNESS:.0f}): "
            "it follows branches, not the stem, which is hidden"
        )
        stem = None
    elif stem is None:
        note = (
            f"no stem circle at {params.breast_height_m} m above the base "
            f"({int(in_slice.sum())} points in the slice, "
            f"{int((in_slice & surface).sum())} on bark-like surfaces): the stem may "
            "be hidden by branches, or the cloud holds ground or several trees"
        )
    reporter.check_cancelled()
    area, width = _crown(xyz[:, :2])
    return TreeMeasures(
        n_points=len(xyz),
        base_z=base,
        height_m=height,
        dbh_m=2 * stem.radius_m if stem is not None else float("nan"),
        stem=stem,
        crown_area_m2=area,
        crown_width_m=width,
        note=note,
    )


def measure_registration(
    target: Cloud,
    source: Cloud,
    T_target_source: Transform,
    params: MeasureParams | None = None,
    reporter: Reporter = NULL_REPORTER,
) -> dict[str, TreeMeasures]:
    """Measure the target, the moved source and both merged, in the target frame.

    Parameters
    ----------
    target, source : Cloud
        The scans as read.
    T_target_source : (4, 4) float64
        World-frame transform from source to target.
    params : MeasureParams, optional

    Returns
    -------
    dict
        ``{"target": ..., "source": ..., "merged": ...}`` of TreeMeasures. The merged
        base is the lower of the two; each scan is measured on its own points.
    """
    T = np.asarray(T_target_source, dtype=np.float64)
    tgt = target.world_xyz
    src = source.world_xyz @ T[:3, :3].T + T[:3, 3]
    reporter.check_cancelled()
    return {
        "target": measure_tree(tgt, params, reporter),
        "source": measure_tree(src, params, reporter),
        "merged": measure_tree(np.vstack([tgt, src]), params, reporter),
    }
