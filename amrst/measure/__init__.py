"""Tree measurements: height, stem diameter at breast height (DBH) and crown size.

Beyond the paper. Two scans are registered to measure one whole tree; a single TLS scan
sees only the half of the stem facing the scanner, so its DBH rests on a half circle.
:func:`measure_registration` measures the target, the moved source and the two merged,
so the report shows what the merge gained (the stem arc seen, in degrees).

- **Height**: top minus base, both taken on points that have neighbours (a stray point
  metres above the crown or below the base is not the tree). The base is the lowest
  points at the stem (:mod:`amrst.measure.dbh`): in a field clip with ground, the
  ground under the stem, not the lowest ground of the clip.
- **DBH**: circles fitted to the stem in thin horizontal slices around breast height
  above the base (RANSAC on three-point circles, so branches and leaves in a slice do
  not pull it, then a geometric least-squares fit on the inliers); the DBH is the
  median diameter of the slices' circles that agree (:mod:`amrst.measure.dbh`).
  ``arc_deg`` is how much of the circumference the inliers cover (360 minus the
  largest angular gap). On the merged cloud the circles rest on both scans' arcs.
- **Crown**: the area of the convex hull of all points seen from above, and the crown
  width, the mean of its extents along the hull's two principal axes (the mean of two
  perpendicular crown widths that field crews measure).

The cloud should hold one tree; in a field clip around the tree, ground, shrubs and
neighbours may stay (the stem nearest the middle of the clip is measured).
:func:`dbh_check` says when a DBH should not be trusted.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field
from typing import TYPE_CHECKING, Any

import numpy as np

from amrst.measure.dbh import breast_height_stem, with_company
from amrst.measure.stem import StemCircle, fit_stem_circle
from amrst.progress import NULL_REPORTER
from amrst.stages.voxels import sorted_unique

if TYPE_CHECKING:
    from collections.abc import Mapping

    from amrst.progress import Reporter
    from amrst.types import Cloud, Transform

__all__ = [
    "MeasureParams",
    "StemCircle",
    "TreeMeasures",
    "dbh_check",
    "distinct_points",
    "fit_stem_circle",
    "measure_registration",
    "measure_tree",
]


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


_CROWN_GRID_M = 0.05
# Points closer than this are one point to the measurements (no-return copies, ...).
_DUPLICATE_M = 0.0005


@dataclass(frozen=True, slots=True)
class TreeMeasures:
    """What a forester reads off one (merged) tree cloud.

    ``n_points`` is the size of the tree cloud; ``n_points_measured`` the points the
    figures came from (a bounded sample of a big cloud, see :mod:`amrst.sampling`),
    None in documents written before it was recorded.
    """

    n_points: int
    base_z: float  # world z of the base under the stem (m)
    height_m: float
    dbh_m: float  # NaN when no stem circle was found at breast height
    stem: StemCircle | None
    crown_area_m2: float
    crown_width_m: float
    note: str  # why DBH is missing, or ""
    n_points_measured: int | None = None
    dbh_doubt: str = ""  # why the stem circles do not bear the DBH out, or ""

    def as_dict(self) -> dict[str, Any]:
        """Return plain numbers for JSON/CSV (stem fields flattened, NaN kept)."""
        out: dict[str, Any] = {
            "n_points": self.n_points,
            "n_points_measured": self.n_points_measured,
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
        if self.dbh_doubt:
            out["dbh_doubt"] = self.dbh_doubt
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


def _base_and_top(xyz: np.ndarray, weight: np.ndarray) -> tuple[float, float]:
    z = xyz[:, 2]
    k = min(len(z), max(50, len(z) // 200))  # the lowest and highest 0.5 %
    order = np.argpartition(z, (k - 1, len(z) - k)) if len(z) > 2 * k else np.argsort(z)
    low = with_company(xyz, weight, order[:k])
    high = with_company(xyz, weight, order[-k:])
    base = float(z[low].min()) if len(low) else float(np.percentile(z, 0.5))
    top = float(z[high].max()) if len(high) else float(np.percentile(z, 99.5))
    return base, top


def distinct_points(
    xyz: np.ndarray, cell_m: float = _DUPLICATE_M
) -> tuple[np.ndarray, np.ndarray]:
    """One point per ``cell_m`` cube that holds any, and how many each stands for.

    TLS exports keep no-return points as copies of one position (a million
    at the origin); neighbour searches among copies cost the square of their number.
    Points closer than ``cell_m`` carry no shape the measurements can see.

    Parameters
    ----------
    xyz : (N, 3) float64
    cell_m : float

    Returns
    -------
    (M, 3) float64, (M,) int64
        The first input point of each occupied cell (input order), and its count.
    """
    if len(xyz) == 0:
        return xyz, np.zeros(0, np.int64)
    cells = np.floor((xyz - xyz.min(axis=0)) / cell_m).astype(np.int64)
    if cells.max() < 1 << 21:  # one int64 key per cell: a plain sort, not a row sort
        cells = (cells[:, 0] << 42) | (cells[:, 1] << 21) | cells[:, 2]
        _, first, inverse = np.unique(cells, return_index=True, return_inverse=True)
    else:
        _, first, inverse = np.unique(
            cells, axis=0, return_index=True, return_inverse=True
        )
    weight = np.bincount(inverse.reshape(-1), minlength=len(first))
    order = np.argsort(first, kind="stable")
    return xyz[first[order]], weight[order]


def _crown(xy: np.ndarray) -> tuple[float, float]:
    """Convex-hull area (m2) and mean principal-axis width (m) of the points seen from above."""
    from scipy.spatial import ConvexHull, QhullError

    cells = np.floor(xy / _CROWN_GRID_M).astype(np.int64)
    low = cells.min(axis=0) if len(cells) else np.zeros(2, np.int64)
    cells -= low
    if len(cells) and cells.max() < 1 << 31:
        # One int64 key per cell, in the same (x, y) order as unique(axis=0): a
        # plain sort, which releases the GIL (unique(axis=0) sorts a structured
        # view holding it, which stalls the app's window).
        keys = sorted_unique((cells[:, 0] << 32) | cells[:, 1])
        cells = np.stack([keys >> 32, keys & 0xFFFFFFFF], axis=1)
    else:
        cells = np.unique(cells, axis=0)
    cells += low
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
    n_points: int | None = None,
) -> TreeMeasures:
    """Measure one tree cloud.

    Parameters
    ----------
    xyz : (N, 3) float64
        World (or any common-frame) coordinates of one tree, z up (m), or a sample
        of them.
    params : MeasureParams, optional
    n_points : int, optional
        Size of the tree cloud ``xyz`` was sampled from; ``len(xyz)`` when None.

    Returns
    -------
    TreeMeasures
    """
    params = params or MeasureParams()
    xyz = np.asarray(xyz, dtype=np.float64)
    size = len(xyz) if n_points is None else n_points
    xyz = xyz[np.all(np.isfinite(xyz), axis=1)]
    n_measured = len(xyz)
    if n_measured < 3:
        nan = float("nan")
        return TreeMeasures(
            size, nan, nan, nan, None, nan, nan, "too few points", n_measured
        )
    xyz, weight = distinct_points(xyz)  # linear in the copies
    reporter.check_cancelled()
    base, top = _base_and_top(xyz, weight)
    reporter.check_cancelled()
    at = breast_height_stem(xyz, weight, base, top, params, reporter)
    stem = at.stem
    reporter.check_cancelled()
    area, width = _crown(xyz[:, :2])
    return TreeMeasures(
        n_points=size,
        n_points_measured=n_measured,
        base_z=at.base_z,
        height_m=top - at.base_z,
        dbh_m=2 * stem.radius_m if stem is not None else float("nan"),
        stem=stem,
        crown_area_m2=area,
        crown_width_m=width,
        note=at.note,
        dbh_doubt=at.doubt,
    )


def measure_registration(
    target: Cloud,
    source: Cloud,
    T_target_source: Transform,
    params: MeasureParams | None = None,
    reporter: Reporter = NULL_REPORTER,
    sizes: tuple[int, int] | None = None,
) -> dict[str, TreeMeasures]:
    """Measure the target, the moved source and both merged, in the target frame.

    Parameters
    ----------
    target, source : Cloud
        The scans as read, or samples of them.
    T_target_source : (4, 4) float64
        World-frame transform from source to target.
    params : MeasureParams, optional
    sizes : (int, int), optional
        Sizes of the target and source scans the samples were drawn from, for each
        measure's ``n_points``; the clouds' own sizes when None.

    Returns
    -------
    dict
        ``{"target": ..., "source": ..., "merged": ...}`` of TreeMeasures, each
        measured on its own points.
    """
    T = np.asarray(T_target_source, dtype=np.float64)
    tgt = target.world_xyz
    src = source.world_xyz @ T[:3, :3].T + T[:3, 3]
    reporter.check_cancelled()
    n_tgt, n_src = (len(target), len(source)) if sizes is None else sizes
    return {
        "target": measure_tree(tgt, params, reporter, n_tgt),
        "source": measure_tree(src, params, reporter, n_src),
        "merged": measure_tree(np.vstack([tgt, src]), params, reporter, n_tgt + n_src),
    }


#: Two DBHs agree within the larger of these; a DBH above this share of the tree's
#: height is implausible (the stoutest trees stay under about 6 cm per metre).
DBH_AGREE_M = 0.03
DBH_AGREE_FRACTION = 0.15
DBH_PER_HEIGHT = 0.06
#: A merged stem circle seen over less of the circumference than this rests on one
#: side of the stem, no more than one scan sees: the scans saw the same side, and a
#: short arc of an irregular stem fits circles of many sizes.
MERGED_MIN_ARC_DEG = 180.0


def dbh_check(tree: Mapping[str, TreeMeasures]) -> str:
    """Say why the merged tree's DBH should not be trusted; "" when nothing is wrong.

    The merged DBH is doubted when its stem circles around breast height disagree,
    when they rest on one side of the stem, when the scans' own DBHs disagree, when
    it lies outside both of them, or when it is implausible for the tree's height.

    Parameters
    ----------
    tree : mapping of str to TreeMeasures
        ``"target"``, ``"source"`` and ``"merged"``, as a registration measures them.

    Returns
    -------
    str
        One sentence for the technician, or "".
    """
    merged = tree.get("merged")
    if merged is None or not math.isfinite(merged.dbh_m):
        return ""
    own = [
        m.dbh_m
        for k in ("target", "source")
        if (m := tree.get(k)) is not None and math.isfinite(m.dbh_m)
    ]

    def apart(a: float, b: float) -> bool:
        return abs(a - b) > max(DBH_AGREE_M, DBH_AGREE_FRACTION * min(a, b))

    if merged.dbh_doubt:
        return f"{merged.dbh_doubt}: check the 1.3 m stem slice"
    if merged.stem is not None and merged.stem.arc_deg < MERGED_MIN_ARC_DEG:
        return (
            f"the merged stem circle rests on {merged.stem.arc_deg:.0f}° of the stem, "
            "one side of it: check the 1.3 m stem slice"
        )
    if len(own) == 2 and apart(*own):
        return (
            f"the scans' DBHs disagree ({own[0] * 100:.1f} and {own[1] * 100:.1f} cm): "
            "check the 1.3 m stem slice"
        )
    if own and all(apart(merged.dbh_m, d) for d in own):
        return (
            f"the merged DBH ({merged.dbh_m * 100:.1f} cm) differs from each scan's "
            f"({', '.join(f'{d * 100:.1f}' for d in own)} cm): check the 1.3 m slice"
        )
    if merged.height_m > 0 and merged.dbh_m > DBH_PER_HEIGHT * merged.height_m:
        return (
            f"a DBH of {merged.dbh_m * 100:.0f} cm is implausible for a "
            f"{merged.height_m:.1f} m tree: check the 1.3 m slice"
        )
    return ""
