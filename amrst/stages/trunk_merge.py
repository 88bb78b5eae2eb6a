"""Trunk-search solutions into the ranking: scored, narrowed and merged.

After the heading search (``amrst.stages.trunk``) and the fine registration of its best
headings, these functions score each refined heading as the coarse stage scores its
candidates, pick the close contenders that deserve a full fine fit, and add the
solutions to the ranked list as candidates of origin ``Origin.TRUNK``.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from amrst.stages.coarse import (
    Candidate,
    CandidateList,
    CoarseParams,
    Origin,
    choose_coarse,
    distinct_solutions,
    verification_sample,
)

if TYPE_CHECKING:
    from collections.abc import Sequence

    from scipy.spatial import cKDTree

    from amrst.stages.trunk import TrunkBase, TrunkSearchResult
    from amrst.types import Transform


def score_transforms(
    transforms: list[Transform],
    target_tree: cKDTree,
    source_xyz: np.ndarray,
    params: CoarseParams,
    precise_dist_m: float,
) -> tuple[np.ndarray, np.ndarray]:
    """Score each transform by the share of sampled source points near the target.

    Shares within ``tight_dist_m`` and within ``precise_dist_m`` of the target (the
    same seeded sample as the ranking uses). ``target_tree`` is a cKDTree on the
    target points.
    """
    sample = verification_sample(source_xyz, params)[0]
    reach = max(params.tight_dist_m, precise_dist_m)
    out = np.zeros((2, len(transforms)))
    for k, T in enumerate(transforms):
        d = target_tree.query(
            sample @ T[:3, :3].T + T[:3, 3], distance_upper_bound=reach
        )[0]
        out[:, k] = np.mean(d < params.tight_dist_m), np.mean(d < precise_dist_m)
    return out[0], out[1]


def trunk_contenders(
    close: np.ndarray,
    share: float,
    transforms: Sequence[Transform] | None = None,
    centre: np.ndarray | None = None,
) -> list[int]:
    """Pick the headings that get the full fine registration.

    Parameters
    ----------
    close : (K,) float
        Each kept heading's share of close points after the quick fine registration.
    share : float
        ``TrunkParams.contender_share``.
    transforms : sequence of K (4, 4) float64, optional
        The quick fits; with ``centre``, a heading that landed on the pose of one
        already picked is skipped (refining it again would give the same fit).
    centre : (3,) float64, optional
        Source centre of the same-pose test (local frame).

    Returns
    -------
    list of int
        The best heading first, then every other whose share is at least ``share``
        times the best one's (none when the best has no close point), best first.
    """
    if len(close) == 0:
        return []
    order = [int(k) for k in np.argsort(-np.asarray(close), kind="stable")]
    best = float(close[order[0]])
    picked = [order[0]]
    for k in order[1:]:
        if not (best > 0 and close[k] >= share * best):
            continue
        if (
            transforms is not None
            and centre is not None
            and not all(
                distinct_solutions(transforms[k], transforms[j], centre) for j in picked
            )
        ):
            continue
        picked.append(k)
    return picked


def merge_trunk_solutions(
    candidates: CandidateList,
    search: TrunkSearchResult,
    refined: list[Transform],
    *,
    target_tree: cKDTree,
    source_xyz: np.ndarray,
    params: CoarseParams,
    precise_dist_m: float,
    fine_points: list[str],
) -> CandidateList:
    """Add refined trunk-search solutions to the ranking, scored as the others are.

    Parameters
    ----------
    candidates : CandidateList
        The tetrahedron solutions.
    search : TrunkSearchResult
    refined : list of (4, 4) transforms
        Each ``search.solutions[k]`` after fine registration.
    target_tree : cKDTree on the target points
    source_xyz : (M, 3) float64
    params : CoarseParams
    precise_dist_m : float
        Distance of the precise score that orders the trunk solutions.
    fine_points : list of str
        The point set each solution's fine registration used.

    Returns
    -------
    CandidateList
        Trunk solutions first (best precise score first) when the best of them scores
        above every tetrahedron solution, after them otherwise; ranks renumbered.
    """
    from dataclasses import replace

    scores, precises = score_transforms(
        refined, target_tree, source_xyz, params, precise_dist_m
    )
    # Heading k becomes candidate id `base + k`: callers rely on it (trunk_fallback).
    base = 1 + max((c.id for c in candidates.candidates), default=0)
    tb, sb = search.target_base, search.source_base
    trunk = []
    for k, (sol, T) in enumerate(zip(search.solutions, refined, strict=True)):
        score, precise = float(scores[k]), float(precises[k])
        expl = (
            f"Trunk heading search: trunk bases matched ({_radius_text(tb, 'target')}, "
            f"{_radius_text(sb, 'source')}), heading started at {sol.start_yaw_deg:.0f}°, "
            f"levelled ICP polish, then fine registration on {fine_points[k]} points: {precise:.0%} of sampled source points lie within "
            f"{precise_dist_m * 100:.1f} cm of the target, {score:.0%} within {params.tight_dist_m * 100:.0f} cm. "
            "Not a tetrahedron match."
        )
        trunk.append(
            Candidate(
                id=base + k,
                rank=0,
                score=score,
                raw_score=sol.score,
                support=0,
                volume_m3=float("nan"),
                edge_error=float("nan"),
                svd_residual_m=float("nan"),
                target_idx=np.zeros(0, dtype=np.int64),
                source_idx=np.zeros(0, dtype=np.int64),
                T_match=sol.T_target_source,
                T_target_source=T,
                polished=True,
                explanation=expl,
                origin=Origin.TRUNK,
                precise_score=precise,
                fine_points=fine_points[k],
            )
        )
    trunk.sort(key=lambda c: -c.precise_score)
    tetra = list(candidates.candidates)
    centre = source_xyz.mean(axis=0)

    def verifies(cands: list[Candidate]) -> bool:
        return (
            bool(cands)
            and choose_coarse(
                CandidateList(tuple(cands), 0), frozenset(), centre
            ).verified
        )

    # A verified trunk solution goes above unverified tetrahedron matches, whatever
    # their 4 cm scores; otherwise the higher 4 cm score leads.
    best_tetra = max((c.score for c in tetra), default=-1.0)
    if verifies(trunk) != verifies(tetra):
        first = verifies(trunk)
    else:
        first = bool(trunk) and trunk[0].score > best_tetra
    merged = trunk + tetra if first else tetra + trunk
    merged = [replace(c, rank=r) for r, c in enumerate(merged, start=1)]
    return CandidateList(tuple(merged), candidates.n_matches)


def _radius_text(base: TrunkBase, role: str) -> str:
    if np.isfinite(base.radius_m):
        return f"{role} trunk r = {base.radius_m * 100:.0f} cm"
    return f"{role} trunk centre from the slice median, no circle fitted"
