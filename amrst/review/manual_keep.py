"""Keep the technician's pose when an automatic refinement leaves it.

A manual pose is made by hand because the automatic matching failed, usually because
the scans share little. There, ICP (the candidate polish, Fine registration) can slide
to a wrong pose that happens to overlap more points, with a *higher* score than the
true one. So a refinement of a manual pose is kept only when it stays the same
solution (``CoarseParams.same_solution_m`` / ``_deg``) and does not halve the score;
otherwise the manual pose stays, and the reason says so. No Qt.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import TYPE_CHECKING

import numpy as np

from amrst.types import rotation_angle_deg

if TYPE_CHECKING:
    from scipy.spatial import cKDTree

    from amrst.stages.coarse import CoarseParams
    from amrst.stages.fine import FineResult
    from amrst.types import Transform


CLEAR_LOSS = 0.5  # a refinement that keeps under this share of the score is a loss


@dataclass(frozen=True, slots=True)
class KeepDecision:
    """Whether a refinement of a manual pose is kept, and why.

    Attributes
    ----------
    keep_manual : bool
        True: the refinement is dropped, the manual pose stays.
    turn_deg, shift_m : float
        How far the refinement moved the pose (rotation, and the move of the source
        centre).
    score_manual, score_refined : float
        Share of sampled source points within ``tight_dist_m`` of the target, before
        and after.
    why : str
        One sentence for the log and the status bar.
    """

    keep_manual: bool
    turn_deg: float
    shift_m: float
    score_manual: float
    score_refined: float
    why: str


def judge_refinement(
    T_manual: Transform,
    T_refined: Transform,
    target_xyz: np.ndarray,
    source_xyz: np.ndarray,
    params: CoarseParams,
    what: str = "Fine registration",
    *,
    tree: cKDTree | None = None,
) -> KeepDecision:
    """Decide whether ``T_refined`` (from ``T_manual``) replaces the manual pose.

    Parameters
    ----------
    T_manual, T_refined : (4, 4) float64
        ``T_target_source`` in local frames, before and after the refinement.
    target_xyz, source_xyz : (N, 3), (M, 3) float64
        The preprocessed scans (the ones candidates are verified on).
    params : CoarseParams
        Verification sample, ``tight_dist_m`` and the same-solution thresholds.
    what : str
        The refinement's name, for the sentence.
    tree : scipy.spatial.cKDTree or None
        A KD-tree of ``target_xyz`` already built (None: built here).

    Returns
    -------
    KeepDecision
    """
    from scipy.spatial import cKDTree

    from amrst.stages.coarse import verification_sample

    sample, _rng = verification_sample(source_xyz, params)
    tree = cKDTree(target_xyz) if tree is None else tree

    def share(
        T: Transform,
    ) -> float:  # amrst.review.manual.tight_share, without the cycle
        d = tree.query(
            sample @ T[:3, :3].T + T[:3, 3], distance_upper_bound=params.tight_dist_m
        )[0]
        return float(np.mean(d < params.tight_dist_m)) if len(d) else 0.0

    before, after = share(T_manual), share(T_refined)
    centre = np.median(source_xyz, axis=0) if len(source_xyz) else np.zeros(3)
    turn = rotation_angle_deg(T_refined[:3, :3] @ T_manual[:3, :3].T)
    shift = float(
        np.linalg.norm(
            (T_refined[:3, :3] @ centre + T_refined[:3, 3])
            - (T_manual[:3, :3] @ centre + T_manual[:3, 3])
        )
    )
    moved_away = turn > params.same_solution_deg or shift > params.same_solution_m
    # Small score changes mean little (Fine may lower the score a little while the
    # true error falls); a halving does.
    worse = after < CLEAR_LOSS * before
    scores = f"score {before:.1%} -> {after:.1%}"
    if moved_away:
        why = (
            f"{what} moved your manual pose {turn:.1f}° and {shift * 100:.0f} cm, "
            f"to another solution ({scores}): your pose is kept. Scans that share "
            "little let ICP slide; check the slices, add point pairs, or try Fine "
            "with fine.points = all and a smaller max_corr_dist_m."
        )
    elif worse:
        why = (
            f"{what} lowered the score of your manual pose ({scores}): your pose is "
            "kept."
        )
    else:
        why = (
            f"{what} refined your manual pose by {turn:.2f}° and "
            f"{shift * 100:.1f} cm ({scores})."
        )
    return KeepDecision(moved_away or worse, turn, shift, before, after, why)


def keep_manual(
    fine: FineResult,
    T_manual: Transform,
    target_xyz: np.ndarray,
    source_xyz: np.ndarray,
    params: CoarseParams,
    *,
    tree: cKDTree | None = None,
) -> tuple[FineResult, KeepDecision]:
    """Return Fine's result from the manual pose ``T_manual``, or that pose kept.

    :func:`judge_refinement` decides; a dropped result keeps Fine's method and says
    so in it, with the manual pose as ``T_target_source``.
    """
    kept = judge_refinement(
        T_manual, fine.T_target_source, target_xyz, source_xyz, params, tree=tree
    )
    if kept.keep_manual:
        fine = replace(
            fine,
            T_target_source=np.asarray(T_manual, float),
            method=f"{fine.method} (result dropped: manual pose kept)",
        )
    return fine, kept
