"""One plain dict that describes a registration: metrics, timings, truth errors.

The CLI writes it as metrics.json, the app shows it in its Metrics panel and exports it,
the benchmark reads the same numbers.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any, cast

import numpy as np

from amrst.stages.metrics import truth_errors

if TYPE_CHECKING:
    from amrst.pipeline import RegistrationResult
    from amrst.stages.keypoints import KeypointResult
    from amrst.types import Transform


def registration_summary(
    result: RegistrationResult, T_truth: Transform | None = None
) -> dict[str, Any]:
    """Metrics of a registration as a nested JSON-ready dict.

    Parameters
    ----------
    result : RegistrationResult
    T_truth : (4, 4) float64 or None
        Known ``T_target_source`` (world frame); adds rotation/translation errors and gt_rmse.

    Returns
    -------
    dict
    """
    fine, coarse = result.fine, result.coarse
    out: dict[str, Any] = {
        "coarse": {
            **result.metrics_coarse.as_dict(),
            "candidate_rank": coarse.candidate.rank,
            "candidate_id": coarse.candidate.id,
            "verification_score": coarse.candidate.score,
            "confidence": coarse.confidence,
            "verified": coarse.verified,
        },
        "fine": {
            **result.metrics_fine.as_dict(),
            "method": fine.method,
            "converged": fine.converged,
            "iterations": fine.iterations,
            "fitness": fine.fitness,
            "inlier_rmse_m": fine.inlier_rmse_m,
        },
        "key_points": {
            # A finished registration has both scans' key points.
            "target": len(cast("KeypointResult", result.target.keypoints).xyz),
            "source": len(cast("KeypointResult", result.source.keypoints).xyz),
        },
        "tetrahedron_matches": result.matches.n_matches,
        "candidates": len(result.matches.candidates),
        "wood_fraction": {
            "target": result.target.separation.wood_fraction,
            "source": result.source.separation.wood_fraction,
        },
        "timings_s": {k: round(v, 4) for k, v in result.timings.items()},
    }
    if result.tree:
        # Height, DBH and crown of each scan alone and of the merged tree.
        out["tree"] = {name: m.as_dict() for name, m in result.tree.items()}
    if T_truth is not None:
        src = result.source.cloud.world_xyz
        T_truth = np.asarray(T_truth, float)
        fine_err = truth_errors(result.T_target_source, T_truth, src)
        out["truth"] = {
            "fine": fine_err.as_dict(),
            "coarse": truth_errors(result.T_coarse, T_truth, src).as_dict(),
            "registered": fine_err.registered(),
        }
    return out
