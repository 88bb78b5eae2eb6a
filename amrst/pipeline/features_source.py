"""The feature-matcher source: a generic global matcher's pose as one more candidate.

Asked when no tetrahedron match verifies (``global_match.mode`` "fallback"), before the
trunk search: KISS-Matcher (or FPFH + RANSAC) on the points the tree stages use, then
the coarse stage's own polish and tight score, so its candidate is verified exactly as
a tetrahedron solution is. When it lands on a solution already in the list, that
candidate names both sources instead of a second row appearing.
"""

from __future__ import annotations

import logging
from dataclasses import replace
from typing import TYPE_CHECKING

import numpy as np

from amrst.stages.candidates import wants_more
from amrst.stages.coarse import (
    Candidate,
    CandidateList,
    Origin,
    choose_coarse,
    distinct_solutions,
    verification_sample,
)
from amrst.stages.global_match import match_globally

if TYPE_CHECKING:
    from amrst.params import RegistrationParams
    from amrst.pipeline.analysis import ScanAnalysis
    from amrst.progress import Reporter
    from amrst.stages.fine import FineResult

log = logging.getLogger(__name__)
_POLISH_POINTS = 500


def wants_features(
    ranked: CandidateList, params: RegistrationParams, centre: np.ndarray
) -> bool:
    """Tell whether to ask the matcher: mode "always", or nothing verifies yet."""
    return wants_more(ranked, params.global_match.mode, centre)


def add_feature_solution(
    ranked: CandidateList,
    target: ScanAnalysis,
    source: ScanAnalysis,
    params: RegistrationParams,
    reporter: Reporter,
    threads: int,
) -> tuple[CandidateList, dict[int, FineResult]]:
    """Match globally, polish and verify the pose, and merge it into the list.

    Returns the merged list and no finished fine fits. ``threads`` is not used: the
    feature matcher always runs on one thread (``match_globally``), so that its pose
    is the same on every run.
    """
    from scipy.spatial import cKDTree

    from amrst.stages.polish import polish
    from amrst.stages.voxels import voxel_sample

    reporter.check_cancelled()
    found = match_globally(target.xyz, source.xyz, params.global_match)
    reporter.progress(0.7, f"feature matcher ({found.method})")
    if not found.found:
        log.info("The feature matcher (%s) found no pose", found.method)
        return ranked, {}
    cp = params.coarse
    sample, rng = verification_sample(source.xyz, cp)
    tgt_small = target.xyz[voxel_sample(target.xyz, cp.verify_voxel_m)]
    src_small = source.xyz[voxel_sample(source.xyz, cp.verify_voxel_m)]
    if len(src_small) > _POLISH_POINTS:
        src_small = src_small[rng.choice(len(src_small), _POLISH_POINTS, replace=False)]
    T0 = found.T_target_source
    T = polish(
        src_small, tgt_small, cKDTree(tgt_small), T0[None], cp.polish_max_dist_m
    )[0]
    tree = cKDTree(target.xyz)
    raw, score = (
        float(
            np.mean(
                tree.query(
                    sample @ M[:3, :3].T + M[:3, 3],
                    distance_upper_bound=cp.tight_dist_m,
                )[0]
                < cp.tight_dist_m
            )
        )
        for M in (T0, T)
    )
    centre = source.xyz.mean(axis=0)
    for k, c in enumerate(ranked.candidates):
        if not distinct_solutions(c.T_target_source, T, centre):
            # Found already: one candidate naming both sources.
            named = replace(
                c,
                also_found_by=(*c.also_found_by, Origin.FEATURES),
                explanation=f"{c.explanation} The feature matcher ({found.method}) found it too.",
            )
            cands = list(ranked.candidates)
            cands[k] = named
            return CandidateList(tuple(cands), ranked.n_matches), {}
    expl = (
        f"Feature matcher ({'KISS-Matcher' if found.method == 'kiss' else 'FPFH + RANSAC'}, "
        f"{found.n_inliers} inlier correspondences): {score:.0%} of sampled source points "
        f"lie within {cp.tight_dist_m * 100:.0f} cm of the target after a short ICP polish "
        f"({raw:.0%} under its own pose). Not a tetrahedron match."
    )
    new = Candidate(
        id=1 + max((c.id for c in ranked.candidates), default=0),
        rank=0,
        score=score,
        raw_score=raw,
        support=0,
        volume_m3=float("nan"),
        edge_error=float("nan"),
        svd_residual_m=float("nan"),
        target_idx=np.zeros(0, dtype=np.int64),
        source_idx=np.zeros(0, dtype=np.int64),
        T_match=T0,
        T_target_source=T,
        polished=True,
        explanation=expl,
        origin=Origin.FEATURES,
    )
    merged = _insert(list(ranked.candidates), new, centre)
    reporter.progress(1.0, f"feature matcher: score {score:.0%}")
    return CandidateList(tuple(merged), ranked.n_matches), {}


def _insert(
    cands: list[Candidate], new: Candidate, centre: np.ndarray
) -> list[Candidate]:
    """Insert ``new`` in the ranking, ranks renumbered.

    First when it verifies and the current leader does not, or when it scores above
    every polished non-trunk candidate; after the polished ones otherwise.
    """
    leader_ok = (
        bool(cands)
        and choose_coarse(CandidateList(tuple(cands), 0), frozenset(), centre).verified
    )
    new_ok = choose_coarse(CandidateList((new,), 0), frozenset(), centre).verified
    best = max(
        (c.score for c in cands if c.polished and c.origin is not Origin.TRUNK),
        default=-1.0,
    )
    if (new_ok and not leader_ok) or (new_ok == leader_ok and new.score > best):
        out = [new, *cands]
    else:
        k = next((i for i, c in enumerate(cands) if not c.polished), len(cands))
        out = [*cands[:k], new, *cands[k:]]
    return [replace(c, rank=r) for r, c in enumerate(out, start=1)]
