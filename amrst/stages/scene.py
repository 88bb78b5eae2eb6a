"""Scene understanding: ground, the tree of interest, and everything else.

Scans from the field hold more than the tree: the ground, parts of neighbouring trees
and shrubs, cut out with a cylinder around the stem. Before the tree stages run, this
stage labels each point:

1. ``GROUND``: points within ``ground_dist_m`` of the ground surface (``ground.py``:
   a levelled plane under the lowest points plus relief). No ground is declared on a
   clean, segmented tree, and then nothing else changes (every point is ``TREE``).
2. Stems: connected clusters in a slice ``stem_low_m``..``stem_high_m`` above the
   ground that span the slice's height and are narrower than ``stem_max_width_m``
   (shrubs are lower, crowns wider); centre and radius from a circle fit.
3. The tree of interest: the stem nearest the clip axis (the centre of the scan's
   footprint, as a cylinder cut leaves it) or nearest a position the user gives.
4. ``TREE`` / ``OTHER``: every point above the ground goes to the stem it reaches by
   the shortest path through neighbouring points (links up to ``link_m``); pieces
   that reach no stem are ``OTHER`` when low (shrubs) and go with the nearest labelled
   point when high (crown parts cut off by occlusion).

The tree base is where the chosen stem meets the ground surface, not the lowest point
of the file.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from amrst.stages.ground import fit_ground

TREE, GROUND, OTHER = 0, 1, 2
LABEL_NAMES = ("tree", "ground", "other")
SCENE_MODES = ("auto", "off")
SCENE_POINTS = ("above_ground", "tree")
MAX_GROUND_POINTS = 500_000
# Two levelled scanners (residual tilt up to 2 deg each) see one ground tilted by at
# most 4 deg apart; a little more for the fit.
TILT_MARGIN_DEG = 5.0


@dataclass(frozen=True, slots=True, kw_only=True)
class SceneParams:
    """Ground, stems and the tree of interest."""

    mode: str = field(
        default="auto",
        metadata={
            "choices": SCENE_MODES,
            "help": "auto: find ground and neighbours when the scan has a ground (a clean tree is left as it is); off: treat every point as the tree.",
        },
    )
    use_points: str = field(
        default="above_ground",
        metadata={
            "choices": SCENE_POINTS,
            "help": "Points the tree stages get: above_ground (tree, neighbours and shrubs: the whole scene is rigid, so neighbours are extra anchors) or tree (the tree of interest alone).",
        },
    )
    cell_m: float = field(
        default=0.5,
        metadata={
            "unit": "m",
            "min": 0.05,
            "max": 5.0,
            "help": "Grid cell of the ground fit.",
        },
    )
    ground_tol_m: float = field(
        default=0.15,
        metadata={
            "unit": "m",
            "min": 0.01,
            "max": 2.0,
            "help": "A cell's lowest point within this of the plane is on the ground.",
        },
    )
    ground_dist_m: float = field(
        default=0.15,
        metadata={
            "unit": "m",
            "min": 0.0,
            "max": 2.0,
            "help": "Points less than this above the ground surface are ground.",
        },
    )
    max_slope_deg: float = field(
        default=20.0,
        metadata={
            "unit": "deg",
            "min": 0.0,
            "max": 60.0,
            "help": "Steepest ground considered.",
        },
    )
    min_ground_area_m2: float = field(
        default=12.0,
        metadata={
            "unit": "m²",
            "min": 0.0,
            "max": 1e6,
            "help": "Ground area a scan must show to have a ground (clean trees: at most 7.5 m² of stem foot on a plane).",
        },
    )
    expected_ground_area_m2: float = field(
        default=4.0,
        metadata={
            "unit": "m²",
            "min": 0.0,
            "max": 1e6,
            "help": "The same test when the other scan of the pair has a ground (field case 09: a scan whose ground is hidden showed a 3 m² plane on shrub bases, which is not a ground).",
        },
    )
    stem_low_m: float = field(
        default=0.3,
        metadata={
            "unit": "m",
            "min": 0.0,
            "max": 5.0,
            "help": "Bottom of the stem slice above the ground.",
        },
    )
    stem_high_m: float = field(
        default=1.5,
        metadata={
            "unit": "m",
            "min": 0.1,
            "max": 10.0,
            "help": "Top of the stem slice above the ground (shrubs lower than this are not stems).",
        },
    )
    stem_max_width_m: float = field(
        default=2.5,
        metadata={
            "unit": "m",
            "min": 0.05,
            "max": 10.0,
            "help": "Widest stem cluster in the slice (buttresses included).",
        },
    )
    link_m: float = field(
        default=0.15,
        metadata={
            "unit": "m",
            "min": 0.01,
            "max": 2.0,
            "help": "Longest link between neighbouring points when clusters and paths are traced.",
        },
    )
    crown_height_m: float = field(
        default=1.5,
        metadata={
            "unit": "m",
            "min": 0.0,
            "max": 20.0,
            "help": "A piece that reaches no stem goes with its nearest labelled neighbour when higher than this; lower, it is a shrub (other).",
        },
    )
    seed: int = field(
        default=0, metadata={"min": 0, "help": "Seed of the ground RANSAC."}
    )

    def __post_init__(self) -> None:
        if self.mode not in SCENE_MODES:
            raise ValueError(f"scene mode must be one of {SCENE_MODES}")
        if self.use_points not in SCENE_POINTS:
            raise ValueError(f"scene.use_points must be one of {SCENE_POINTS}")
        if self.stem_low_m >= self.stem_high_m:
            raise ValueError(
                f"scene.stem_low_m ({self.stem_low_m} m) must be below "
                f"scene.stem_high_m ({self.stem_high_m} m)"
            )


@dataclass(frozen=True, slots=True)
class Stem:
    """One stem found in the slice above the ground."""

    xy: np.ndarray  # (2,) centre of the fitted circle (local frame)
    radius_m: float  # nan when the circle fit was not usable
    n_points: int


@dataclass(frozen=True, slots=True)
class SceneResult:
    """Per-point labels and what the scene holds."""

    labels: np.ndarray  # (N,) int8: TREE, GROUND or OTHER
    height_m: (
        np.ndarray
    )  # (N,) height above the ground surface (above the lowest point without ground)
    has_ground: bool
    ground_plane: np.ndarray  # (3,) z = a x + b y + c
    ground_area_m2: float
    ground_tilt_deg: float  # plane normal against the scan's z axis
    stems: tuple[Stem, ...]  # nearest the axis (or the given stem) first
    tree_stem: int  # index of the tree of interest in stems; -1 when none
    base: np.ndarray | None  # (3,) where the tree's stem meets the ground
    axis_xy: np.ndarray  # (2,) clip axis (footprint centre) or the given stem
    message: str

    def keep(self, use_points: str = "above_ground") -> np.ndarray:
        """(N,) bool: the points the tree stages get (see ``SceneParams.use_points``)."""
        if use_points == "tree" and self.has_ground:
            return np.asarray(self.labels == TREE)
        return np.asarray(self.labels != GROUND)

    def counts(self) -> dict[str, int]:
        """Points per label name."""
        return {n: int(np.sum(self.labels == k)) for k, n in enumerate(LABEL_NAMES)}


def understand_scene(
    xyz: np.ndarray,
    params: SceneParams,
    stem_xy: np.ndarray | None = None,
    expect_ground: float | None = None,
    ground_xyz: np.ndarray | None = None,
) -> SceneResult:
    """Label ground, the tree of interest and other points of one scan.

    Parameters
    ----------
    xyz : (N, 3) float64
        Preprocessed points, local frame.
    params : SceneParams
    stem_xy : (2,) float64 or None
        A stem position the user gives (local frame); default: the footprint centre.
    expect_ground : float or None
        The ground tilt (deg) of the other scan of the pair when it has a ground: then
        ``expected_ground_area_m2`` is enough, and the plane may tilt at most
        ``tilt_margin_deg`` more than that one (both scanners are about level).
    ground_xyz : (M, 3) float64 or None
        Points to fit the ground on, same frame (default ``xyz``): the scan before its
        outlier filter, which removes much of the sparse far ground. At most
        ``MAX_GROUND_POINTS`` of them are used (an even stride).

    Returns
    -------
    SceneResult
        Every point ``TREE`` when ``mode`` is off or no ground is found.
    """
    xyz = np.asarray(xyz, dtype=float)
    n = len(xyz)
    axis = (
        np.asarray(stem_xy, dtype=float).reshape(2)
        if stem_xy is not None
        else (xyz[:, :2].min(axis=0) + xyz[:, :2].max(axis=0)) / 2
        if n
        else np.zeros(2)
    )
    labels = np.full(n, TREE, dtype=np.int8)
    if params.mode == "off" or n < 10:
        return _no_ground(labels, xyz, axis, "scene analysis off")
    gxyz = xyz if ground_xyz is None else np.asarray(ground_xyz, dtype=float)
    gxyz = gxyz[np.isfinite(gxyz).all(axis=1)]
    if len(gxyz) > MAX_GROUND_POINTS:
        gxyz = gxyz[:: int(np.ceil(len(gxyz) / MAX_GROUND_POINTS))]
    ground = fit_ground(
        gxyz,
        cell_m=params.cell_m,
        tol_m=params.ground_tol_m,
        max_slope_deg=(
            params.max_slope_deg
            if expect_ground is None
            else min(params.max_slope_deg, expect_ground + TILT_MARGIN_DEG)
        ),
        min_area_m2=(
            params.min_ground_area_m2
            if expect_ground is None
            else params.expected_ground_area_m2
        ),
        iterations=300,
        seed=params.seed,
    )
    if not ground.found:
        return _no_ground(
            labels,
            xyz,
            axis,
            f"no ground ({ground.area_m2:.1f} m² on a plane under the lowest points): "
            "treated as a segmented tree",
        )
    h = ground.height(xyz)
    labels[h < params.ground_dist_m] = GROUND
    above = np.flatnonzero(labels != GROUND)
    stems, slice_labels, slice_idx = _find_stems(xyz, h, above, params)
    order = sorted(
        range(len(stems)), key=lambda k: float(np.linalg.norm(stems[k].xy - axis))
    )
    stems = [stems[k] for k in order]
    seeds = [slice_idx[slice_labels == k] for k in order]
    tree_stem = 0 if stems else -1
    if stems:
        owner = _assign_to_stems(xyz, h, above, seeds, params)
        labels[above[owner != 0]] = OTHER
        base_xy = stems[0].xy
        # Where the stem meets the ground: the surface height of the nearest points.
        near = np.linalg.norm(xyz[:, :2] - base_xy, axis=1)
        close = np.argsort(near)[: min(20, n)]
        base = np.r_[base_xy, float(np.median(xyz[close, 2] - h[close]))]
    else:
        base = None
    counts = {nm: int(np.sum(labels == k)) for k, nm in enumerate(LABEL_NAMES)}
    msg = (
        f"ground {ground.area_m2:.0f} m² (tilt {ground.tilt_deg:.1f}°), "
        f"{len(stems)} stem(s); points: {counts['tree']} tree, {counts['ground']} ground, "
        f"{counts['other']} other"
    )
    return SceneResult(
        labels,
        h,
        True,
        ground.plane,
        ground.area_m2,
        ground.tilt_deg,
        tuple(stems),
        tree_stem,
        base,
        axis,
        msg,
    )


def _no_ground(
    labels: np.ndarray, xyz: np.ndarray, axis: np.ndarray, msg: str
) -> SceneResult:
    z0 = float(xyz[:, 2].min()) if len(xyz) else 0.0
    return SceneResult(
        labels,
        xyz[:, 2] - z0,
        False,
        np.array([0.0, 0.0, z0]),
        0.0,
        0.0,
        (),
        -1,
        None,
        axis,
        msg,
    )


def _components(pts: np.ndarray, link: float) -> tuple[int, np.ndarray]:
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components
    from scipy.spatial import cKDTree

    pairs = cKDTree(pts).query_pairs(link, output_type="ndarray")
    g = coo_matrix(
        (np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])), shape=(len(pts), len(pts))
    )
    n, lab = connected_components(g, directed=False)
    return int(n), lab


def _find_stems(
    xyz: np.ndarray, h: np.ndarray, above: np.ndarray, params: SceneParams
) -> tuple[list[Stem], np.ndarray, np.ndarray]:
    """Stems in the slice; also each slice point's stem number (-1 none) and index."""
    hs = h[above]
    sl = above[(hs >= params.stem_low_m) & (hs <= params.stem_high_m)]
    if len(sl) < 10:
        return [], np.zeros(0, dtype=np.int64), sl
    n, lab = _components(xyz[sl], params.link_m)
    span = params.stem_high_m - params.stem_low_m
    stems: list[Stem] = []
    out = np.full(len(sl), -1, dtype=np.int64)
    for k in range(n):
        m = lab == k
        if m.sum() < 10:
            continue
        hk = h[sl[m]]
        # A stem crosses the slice: from near its bottom to near its top.
        if (
            hk.min() > params.stem_low_m + 0.25 * span
            or hk.max() < params.stem_high_m - 0.25 * span
        ):
            continue
        pts = xyz[sl[m], :2]
        if np.ptp(pts, axis=0).max() > params.stem_max_width_m:
            continue
        out[m] = len(stems)
        stems.append(_circle(pts))
    return stems, out, sl


def _circle(pts: np.ndarray) -> Stem:
    """Kasa circle fit of a stem slice; the median when the fit is unusable."""
    med = np.median(pts, axis=0)
    x, y = pts[:, 0] - med[0], pts[:, 1] - med[1]
    A = np.column_stack([2 * x, 2 * y, np.ones(len(x))])
    sol = np.linalg.lstsq(A, x * x + y * y, rcond=None)[0]
    r2 = sol[2] + sol[0] ** 2 + sol[1] ** 2
    spread = float(np.max(np.hypot(x, y)))
    if r2 <= 0 or np.sqrt(r2) > max(1.5 * spread, 0.05):
        return Stem(med, float("nan"), len(pts))
    return Stem(med + sol[:2], float(np.sqrt(r2)), len(pts))


def _assign_to_stems(
    xyz: np.ndarray,
    h: np.ndarray,
    above: np.ndarray,
    seeds: list[np.ndarray],
    params: SceneParams,
) -> np.ndarray:
    """Stem number of each point above the ground (0 = the tree), -1 for shrubs."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import dijkstra
    from scipy.spatial import cKDTree

    from amrst.stages.voxels import voxel_representatives

    # Paths are traced on one point per voxel (a third of the link): ten times fewer
    # links than on the 3 cm working points, same labels at this scale.
    reps, owner_of = voxel_representatives(xyz[above], params.link_m / 3)
    pts = xyz[above][reps]
    pairs = cKDTree(pts).query_pairs(params.link_m, output_type="ndarray")
    d = np.linalg.norm(pts[pairs[:, 0]] - pts[pairs[:, 1]], axis=1)
    graph = coo_matrix(
        (d, (pairs[:, 0], pairs[:, 1])), shape=(len(pts), len(pts))
    ).tocsr()
    pos = np.full(len(xyz), -1, dtype=np.int64)
    pos[above] = owner_of  # working point -> its voxel's node
    node_stem = np.full(len(pts), -1, dtype=np.int64)
    for k in range(len(seeds) - 1, -1, -1):  # the tree of interest wins a shared voxel
        node_stem[pos[seeds[k]]] = k
    nodes = np.flatnonzero(node_stem >= 0)
    _, _, sources = dijkstra(
        graph, directed=False, indices=nodes, min_only=True, return_predecessors=True
    )
    owner = np.where(sources >= 0, node_stem[np.maximum(sources, 0)], -1)
    h_nodes = h[above][reps]
    # Pieces that reach no stem: crown parts (high) go with their nearest labelled
    # point, shrubs (low) stay "other".
    lost = np.flatnonzero(owner < 0)
    reached = np.flatnonzero(owner >= 0)
    if len(lost) and len(reached):
        high = lost[h_nodes[lost] > params.crown_height_m]
        nn = cKDTree(pts[reached]).query(pts[high])[1]
        owner[high] = owner[reached[nn]]
    return np.asarray(owner[owner_of])
