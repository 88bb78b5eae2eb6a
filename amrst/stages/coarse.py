"""Verification, ranking and the coarse solution.

Every tetrahedron match proposes a transform. Matches that propose the same transform are
grouped (their count is the *support*), each group is scored by how much of the source
scan lands on the target scan under its transform (voxel occupancy, a cheap and
symmetric-enough test), and the best few are polished with a short ICP and scored again.
All groups are kept, ranked and explained: the user may reject the top one and take the
next. The confidence compares the winner with the best *different* solution.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np

from amrst.neighbours import THREADS
from amrst.progress import NULL_REPORTER, Reporter
from amrst.stages.candidates import (
    DISTINCT_DEG,
    DISTINCT_M,
    Candidate,
    CandidateList,
    CoarseResult,
    Origin,
    choose_coarse,
    distinct_solutions,
    same_solution,
)
from amrst.stages.polish import Occupancy, polish, transform_many

if TYPE_CHECKING:
    from amrst.stages.match import TetraMatches


@dataclass(frozen=True, slots=True, kw_only=True)
class CoarseParams:
    """Verification of candidate matches."""

    verify_voxel_m: float = field(
        default=0.1,
        metadata={
            "unit": "m",
            "min": 0.01,
            "max": 2.0,
            "help": "Voxel size of the overlap test; a source point scores when it lands in or next to an occupied target voxel.",
        },
    )
    verify_points: int = field(
        default=1500,
        metadata={
            "unit": "points",
            "min": 50,
            "max": 100000,
            "help": "Source points sampled for the overlap test (seeded).",
        },
    )
    raw_points: int = field(
        default=400,
        metadata={
            "unit": "points",
            "min": 20,
            "max": 100000,
            "help": "Sampled source points for the first (raw) score of every solution; the polished ones use verify_points.",
        },
    )
    same_solution_m: float = field(
        default=0.3,
        metadata={
            "unit": "m",
            "min": 0.01,
            "max": 10.0,
            "help": "Tetrahedron matches whose transforms move the tree centre less than this apart (and rotate < same_solution_deg) are grouped into one candidate (their count is its support).",
        },
    )
    same_solution_deg: float = field(
        default=3.0,
        metadata={
            "unit": "deg",
            "min": 0.1,
            "max": 90.0,
            "help": "Rotation part of the same-solution test.",
        },
    )
    polish_top: int = field(
        default=4,
        metadata={
            "unit": "solutions",
            "min": 0,
            "max": 100,
            "help": "The best solutions get a short ICP polish and a second score (0 = off).",
        },
    )
    tight_dist_m: float = field(
        default=0.04,
        metadata={
            "unit": "m",
            "min": 0.005,
            "max": 1.0,
            "help": "After the polish, a candidate scores the share of sampled source points within this distance of the target: the true pose wins at tight distances, a biased one only at loose ones.",
        },
    )
    polish_max_dist_m: float = field(
        default=0.5,
        metadata={
            "unit": "m",
            "min": 0.01,
            "max": 5.0,
            "help": "Largest correspondence distance of the polish ICP.",
        },
    )
    max_candidates: int = field(
        default=200,
        metadata={
            "unit": "solutions",
            "min": 1,
            "max": 10000,
            "help": "Solutions kept in the ranked list.",
        },
    )
    seed: int = field(
        default=0,
        metadata={
            "min": 0,
            "help": "Seed of the verification sampling (same inputs give the same ranking).",
        },
    )


POLISH_POINTS = 500


def _group(
    matches: TetraMatches, centre: np.ndarray, params: CoarseParams
) -> list[np.ndarray]:
    """Group matches proposing the same transform; each group best residual first.

    Leader clustering: the match with the lowest SVD residual leads a group of every
    unassigned match whose transform moves the source centre less than
    ``same_solution_m`` from the leader's and whose rotation vector differs by less
    than ``same_solution_deg``; then the next unassigned one leads. Not transitive (a
    chain of small steps cannot merge different solutions) and independent of where
    the coordinate origin is. Neighbours come from a KD-tree (Chebyshev ball).
    """
    from scipy.spatial import cKDTree
    from scipy.spatial.transform import Rotation

    T = matches.T_target_source
    moved = np.einsum("pij,j->pi", T[:, :3, :3], centre) + T[:, :3, 3]
    rotvec = Rotation.from_matrix(T[:, :3, :3]).as_rotvec(degrees=True)
    feat = np.hstack(
        [moved / params.same_solution_m, rotvec / params.same_solution_deg]
    )
    # Neighbour pairs as arrays (query_ball_point's Python lists are slow on
    # thousands of matches), then a CSR adjacency that lists each match's neighbours.
    n = len(T)
    pairs = cKDTree(feat).query_pairs(1.0, p=np.inf, output_type="ndarray")
    rows = np.concatenate([pairs[:, 0], pairs[:, 1]])
    cols = np.concatenate([pairs[:, 1], pairs[:, 0]])
    order = np.argsort(rows, kind="stable")
    cols = cols[order]
    indptr = np.searchsorted(rows[order], np.arange(n + 1))
    residual = np.asarray(matches.svd_residual_m)
    assigned = np.zeros(n, dtype=bool)
    groups = []
    for leader in np.argsort(residual, kind="stable"):
        if assigned[leader]:
            continue
        near = cols[indptr[leader] : indptr[leader + 1]]
        near = near[~assigned[near]]
        # Leader first, then by residual; ties by index (as the sorted lists gave).
        near = near[np.lexsort((near, residual[near]))]
        members = np.concatenate([[leader], near]).astype(np.int64)
        assigned[members] = True
        groups.append(members)
    return groups


def verification_sample(
    source_xyz: np.ndarray, params: CoarseParams
) -> tuple[np.ndarray, np.random.Generator]:
    """Draw the seeded sample of source points every verification score is measured on.

    Also return the generator after drawing it (the ranking draws more from it).
    """
    rng = np.random.default_rng(params.seed)
    n = min(params.verify_points, len(source_xyz))
    return source_xyz[rng.choice(len(source_xyz), n, replace=False)], rng


def rank_candidates(
    matches: TetraMatches,
    target_xyz: np.ndarray,
    source_xyz: np.ndarray,
    params: CoarseParams,
    reporter: Reporter = NULL_REPORTER,
    *,
    threads: int = THREADS,
) -> CandidateList:
    """Group, verify and rank tetrahedron matches.

    Parameters
    ----------
    matches : TetraMatches
    target_xyz : (N, 3) float64
        Target points used for verification (preprocessed scan).
    source_xyz : (M, 3) float64
        Source points used for verification.
    params : CoarseParams
    reporter : Reporter
    threads : int
        Threads for the KD-tree queries.

    Returns
    -------
    CandidateList
    """
    from scipy.spatial import cKDTree

    from amrst.neighbours import NearestTree
    from amrst.stages.voxels import voxel_sample

    if len(matches.T_target_source) == 0:
        return CandidateList((), 0)
    sample, rng = verification_sample(source_xyz, params)
    occ = Occupancy(target_xyz, params.verify_voxel_m)
    groups = _group(matches, source_xyz.mean(axis=0), params)
    reporter.progress(0.3, f"{len(groups)} distinct solutions")
    rep = np.array([g[0] for g in groups])
    T = matches.T_target_source
    # Raw score: a smaller sample, all groups in one vectorised pass.
    few = sample[: params.raw_points]
    hits = np.concatenate(
        [
            occ.hits_many(transform_many(T[chunk], few))
            for chunk in np.array_split(rep, max(1, len(rep) // 256))
        ]
    )
    raw = np.mean(hits, axis=1)
    support = np.array([len(g) for g in groups])
    polished_T = {int(i): T[i] for i in rep}
    score = raw.copy()
    is_polished = np.zeros(len(rep), dtype=bool)
    tgt_tree = cKDTree(target_xyz)
    if params.polish_top > 0:
        # Open3D would do this too, but importing it slows every command down.
        tgt_small = target_xyz[voxel_sample(target_xyz, params.verify_voxel_m)]
        src_small = source_xyz[voxel_sample(source_xyz, params.verify_voxel_m)]
        if len(src_small) > POLISH_POINTS:
            src_small = src_small[
                rng.choice(len(src_small), POLISH_POINTS, replace=False)
            ]
        small_tree = NearestTree(tgt_small, threads)
        top = np.argsort(-(raw + 0.01 * np.log1p(support)), kind="stable")[
            : params.polish_top
        ]
        reporter.check_cancelled()
        Tps = polish(
            src_small, tgt_small, small_tree, T[rep[top]], params.polish_max_dist_m
        )
        # One KD-tree query for every polished solution's moved sample.
        d = tgt_tree.query(
            np.concatenate([sample @ Tp[:3, :3].T + Tp[:3, 3] for Tp in Tps]),
            distance_upper_bound=params.tight_dist_m,
        )[0].reshape(len(Tps), len(sample))
        for j, Tp, dj in zip(top, Tps, d, strict=True):
            polished_T[int(rep[j])] = Tp
            score[j] = float(np.mean(dj < params.tight_dist_m))
            is_polished[j] = True
        reporter.progress(0.9, "verified the best solutions")
    # Every listed solution gets the same tight score, so the column reads one way:
    # the unpolished ones under their tetrahedron transform, on the smaller sample.
    shortlist = np.argsort(-raw, kind="stable")[: params.max_candidates]
    shortlist = np.union1d(shortlist, np.flatnonzero(is_polished))
    rest = shortlist[~is_polished[shortlist]]
    if len(rest):
        # One KD-tree query for all of them: (G, n, 3) moved samples. A point within
        # tight_dist_m of a target point lies on or next to its voxel: only the points
        # the raw score found there are asked (a third to a half of them).
        Tr = T[rep[rest]]
        moved = transform_many(Tr, few)
        near = (
            hits[rest]
            if params.tight_dist_m < params.verify_voxel_m
            else np.ones((len(rest), len(few)), dtype=bool)
        )
        close = np.zeros(near.shape, dtype=bool)
        close[near] = (
            tgt_tree.query(moved[near], distance_upper_bound=params.tight_dist_m)[0]
            < params.tight_dist_m
        )
        score[rest] = np.mean(close, axis=1)
    # Polished solutions first (the polish is part of their verification), then the rest.
    order = shortlist[
        np.lexsort(
            (
                -support[shortlist],
                -raw[shortlist],
                -score[shortlist],
                ~is_polished[shortlist],
            )
        )
    ]
    order = order[: params.max_candidates]
    cands = []
    for rank, j in enumerate(order, start=1):
        i = int(rep[j])
        expl = (
            f"{support[j]} tetrahedron match(es) agree; {score[j]:.0%} of sampled source points "
            f"lie within {params.tight_dist_m * 100:.0f} cm of the target"
            f"{' after a short ICP polish' if is_polished[j] else ' under the tetrahedron fit'} "
            f"({raw[j]:.0%} on or next to a {params.verify_voxel_m * 100:.0f} cm target voxel); "
            f"edge error {matches.edge_error[i]:.1%}, "
            f"SVD residual {matches.svd_residual_m[i] * 100:.1f} cm, volume {matches.volume_m3[i]:.2f} m³."
        )
        cands.append(
            Candidate(
                id=int(j),
                rank=rank,
                score=float(score[j]),
                raw_score=float(raw[j]),
                support=int(support[j]),
                volume_m3=float(matches.volume_m3[i]),
                edge_error=float(matches.edge_error[i]),
                svd_residual_m=float(matches.svd_residual_m[i]),
                target_idx=matches.target_idx[i],
                source_idx=matches.source_idx[i],
                T_match=T[i],
                T_target_source=polished_T[i],
                polished=bool(is_polished[j]),
                explanation=expl,
            )
        )
    reporter.progress(1.0, f"{len(cands)} ranked solutions")
    return CandidateList(tuple(cands), len(T))


__all__ = [
    "DISTINCT_DEG",
    "DISTINCT_M",
    "Candidate",
    "CandidateList",
    "CoarseParams",
    "CoarseResult",
    "Origin",
    "choose_coarse",
    "distinct_solutions",
    "rank_candidates",
    "same_solution",
    "verification_sample",
]
