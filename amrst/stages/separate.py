"""Wood-leaf separation: intensity when the scan has it, geometry always, then connectivity.

Follows the paper's sequence (intensity -> neighbourhood -> voxel, section II.C) and adds
geometry so xyz-only and leafless scans work: wood surfaces and branches are smooth at the
scale of a few centimetres (low surface variation), foliage is scattered. A neighbourhood
vote smooths the per-point decision, and a voxel-connectivity step keeps the trunk and the
main branches whole while dropping small isolated "wood" specks inside the crown.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np

from amrst.neighbours import THREADS
from amrst.progress import NULL_REPORTER, Reporter
from amrst.stages.features import (
    otsu_threshold,
    pairwise_rows,
    shape_features,
    voxel_components,
)
from amrst.stages.voxels import voxel_grid, voxel_representatives

if TYPE_CHECKING:
    from amrst.neighbours import NeighbourTable

MODES = ("auto", "geometry", "intensity", "all_wood")


@dataclass(frozen=True, slots=True, kw_only=True)
class SeparateParams:
    """Wood-leaf separation settings."""

    mode: str = field(
        default="auto",
        metadata={
            "choices": MODES,
            "help": "auto: geometry, plus intensity when the scan has it; geometry; intensity; all_wood (no separation, e.g. leafless trees).",
        },
    )
    scales_k: tuple[int, ...] = field(
        default=(10, 30),
        metadata={
            "unit": "points",
            "min": 4,
            "max": 100,  # a huge k would exhaust memory before any message
            "help": "Neighbourhood sizes (k nearest) for the geometric features; more than one scale is sturdier.",
        },
    )
    curvature_max: float = field(
        default=0.0,
        metadata={
            "unit": "",
            "min": 0.0,
            "max": 0.33,
            "help": "Surface variation λ3/Σλ below which a point looks like wood; 0 = automatic (Otsu, kept within 0.03-0.09).",
        },
    )
    linearity_min: float = field(
        default=0.85,
        metadata={
            "unit": "",
            "min": 0.0,
            "max": 1.0,
            "help": "Linearity (λ1-λ2)/λ1 at the largest scale above which a point is a thin branch (wood).",
        },
    )
    intensity_threshold: float = field(
        default=float("nan"),
        metadata={
            "unit": "intensity units",
            "help": "Intensity above which a point looks like wood; NaN = automatic (Otsu).",
        },
    )
    feature_voxel_m: float = field(
        default=0.06,
        metadata={
            "unit": "m",
            "min": 0.0,
            "max": 0.5,
            "help": "Features and votes are computed at one point per voxel of this size (its neighbourhoods still come from all points) and shared by the voxel's points; 0 = at every point (slower).",
        },
    )
    vote_neighbours: int = field(
        default=12,
        metadata={
            "unit": "points",
            "min": 1,
            "max": 100,
            "help": "Neighbours whose votes smooth each point's class (the paper's neighbourhood step).",
        },
    )
    voxel_size_m: float = field(
        default=0.08,
        metadata={
            "unit": "m",
            "min": 0.01,
            "max": 1.0,
            "help": "Voxel size of the connectivity step. Typical 0.05-0.15.",
        },
    )
    min_component_fraction: float = field(
        default=0.01,
        metadata={
            "unit": "fraction of wood points",
            "min": 0.0,
            "max": 0.5,
            "help": "Wood components smaller than this share of all wood points become leaves.",
        },
    )

    def __post_init__(self) -> None:
        if self.mode not in MODES:
            raise ValueError(f"mode must be one of {MODES}, not {self.mode!r}")
        if not self.scales_k or min(self.scales_k) < 4:
            raise ValueError(
                "scales_k needs at least one scale of 4 or more neighbours"
            )


@dataclass(frozen=True, slots=True)
class SeparationResult:
    """Per-point wood labels of the preprocessed points."""

    is_wood: np.ndarray  # (N,) bool
    method: str  # what was used: "geometry", "geometry+intensity", ...
    curvature_threshold: float
    intensity_threshold: float  # NaN when intensity was not used

    @property
    def wood_fraction(self) -> float:
        """Share of points labelled wood."""
        return float(self.is_wood.mean()) if len(self.is_wood) else 0.0


def _geometry_votes(
    xyz: np.ndarray, neighbours: np.ndarray, params: SeparateParams
) -> tuple[np.ndarray, float]:
    feats = shape_features(xyz, neighbours, params.scales_k)
    curv = np.max([f["curvature"] for f in feats], axis=0)  # smooth at every scale
    thr = params.curvature_max
    if thr <= 0:
        thr = float(np.clip(otsu_threshold(np.sqrt(curv)) ** 2, 0.03, 0.09))
    # Thin branches are not surfaces but lines at the larger scale.
    linear = feats[-1]["linearity"] > params.linearity_min
    return ((curv < thr) | linear).astype(float), thr


def _intensity_votes(
    intensity: np.ndarray, params: SeparateParams
) -> tuple[np.ndarray, float]:
    thr = params.intensity_threshold
    if not np.isfinite(thr):
        thr = otsu_threshold(intensity)
    return (intensity > thr).astype(float), float(thr)


def separate_wood(
    xyz: np.ndarray,
    intensity: np.ndarray | None,
    params: SeparateParams,
    reporter: Reporter = NULL_REPORTER,
    neighbours: NeighbourTable | None = None,
    *,
    threads: int = THREADS,
) -> SeparationResult:
    """Label each point wood or leaf.

    Parameters
    ----------
    xyz : (N, 3) float64
        Preprocessed points.
    intensity : (N,) float or None
        Intensity of the same points, when the scan has it.
    params : SeparateParams
    reporter : Reporter
    neighbours : NeighbourTable or None
        The neighbours of exactly these points (the preprocess query), read instead
        of a new query; the same labels.
    threads : int
        Threads for a new neighbour query.

    Returns
    -------
    SeparationResult
    """
    from amrst.neighbours import knn

    n = len(xyz)
    if params.mode == "all_wood":
        ones = np.ones(n, dtype=bool)
        return SeparationResult(ones, "all_wood", float("nan"), float("nan"))
    # Features at one representative point per feature voxel (its neighbours are taken
    # from all points, so the scales keep their size); the voxel's points share them.
    if params.feature_voxel_m > 0:
        reps, owner = voxel_representatives(xyz, params.feature_voxel_m)
    else:
        reps = owner = np.arange(n)
    # One neighbour query serves every feature scale and the vote.
    k_max = int(min(max(*params.scales_k, params.vote_neighbours), n))
    if neighbours is not None and len(neighbours) == n:
        nbr = neighbours.knn_idx(k_max, reps)
    else:
        nbr = knn(xyz, k_max, xyz[reps], threads)[1]
    votes, methods = [], []
    curv_thr = int_thr = float("nan")
    use_intensity = intensity is not None and np.ptp(intensity) > 0
    if params.mode in ("auto", "geometry") or not use_intensity:
        v, curv_thr = _geometry_votes(xyz, nbr, params)
        votes.append(v[owner])
        methods.append("geometry")
    reporter.progress(0.4, "geometric features")
    reporter.check_cancelled()
    if use_intensity and params.mode in ("auto", "intensity"):
        v, int_thr = _intensity_votes(np.asarray(intensity, float), params)
        votes.append(v)
        methods.append("intensity")
    vote = np.mean(votes, axis=0)
    # Neighbourhood step: each representative takes the mean vote of its neighbours.
    k = int(min(params.vote_neighbours, n))
    # ``vote[nbr[:, :k]].mean(axis=1)`` bit for bit, summed as whole (M,) rows in
    # numpy's order (its per-row sum of k numbers is several times slower).
    if k > 1:
        score = pairwise_rows(np.take(vote, nbr[:, :k].T)[None])[0] / k
    else:
        score = vote[reps]
    score = score[owner]
    candidate = score > 0.5 if len(votes) == 1 else score >= 0.5
    reporter.progress(0.7, "neighbourhood vote")
    reporter.check_cancelled()
    # Voxel step: wood voxels linked by 26-connectivity; small islands become leaves.
    is_wood = np.zeros(n, dtype=bool)
    wood_idx = np.flatnonzero(candidate)
    if len(wood_idx):
        keys, code = voxel_grid(xyz[wood_idx], params.voxel_size_m)
        _, first, inverse = np.unique(code, return_index=True, return_inverse=True)
        uniq = keys[first]
        labels = voxel_components(uniq)  # 26-connectivity: corners touch
        point_labels = labels[inverse.ravel()]
        sizes = np.bincount(point_labels)
        keep = sizes[point_labels] >= max(
            params.min_component_fraction * len(wood_idx), 10
        )
        is_wood[wood_idx[keep]] = True
    reporter.progress(1.0, f"{is_wood.mean():.0%} wood")
    return SeparationResult(is_wood, "+".join(methods), curv_thr, int_thr)
