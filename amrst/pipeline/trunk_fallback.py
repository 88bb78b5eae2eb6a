"""The trunk fallback: candidates from the trunk-anchored heading search.

Offered when no tetrahedron match verifies (scans that saw opposite halves of a crown)
on levelled scans: the trunk bases are matched, the heading is searched, the best
headings get a quick then a full fine registration, and the results join the ranked
list as candidates of origin ``Origin.TRUNK``. The full fits are handed back by
candidate id so that ``register()`` does not run them twice.
"""

from __future__ import annotations

import logging
from dataclasses import replace
from typing import TYPE_CHECKING

from amrst.pipeline.refine import refine
from amrst.progress import Reporter, SubReporter
from amrst.stages.candidates import wants_more
from amrst.stages.trunk import search_yaw
from amrst.stages.trunk_merge import (
    merge_trunk_solutions,
    score_transforms,
    trunk_contenders,
)

if TYPE_CHECKING:
    import numpy as np
    from scipy.spatial import cKDTree

    from amrst.params import RegistrationParams
    from amrst.pipeline.analysis import ScanAnalysis
    from amrst.stages.coarse import CandidateList
    from amrst.stages.fine import FineResult
    from amrst.types import Transform

log = logging.getLogger(__name__)


def wants_trunk_search(
    ranked: CandidateList, params: RegistrationParams, centre: np.ndarray
) -> bool:
    """Tell whether to run the trunk search: mode "always", or nothing verifies yet."""
    if not params.match.levelled:  # the heading search turns about the vertical
        return False
    return wants_more(ranked, params.trunk.mode, centre)


def add_trunk_solutions(
    ranked: CandidateList,
    target: ScanAnalysis,
    source: ScanAnalysis,
    params: RegistrationParams,
    reporter: Reporter,
    threads: int,
) -> tuple[CandidateList, dict[int, FineResult]]:
    """Run the trunk heading search, refine its best headings, add them to the list.

    Returns the merged list and ``{candidate id: FineResult}`` for the solutions that
    already had their full fine registration. ``threads``: for the KD-tree queries.
    """
    from scipy.spatial import cKDTree

    tree = cKDTree(target.xyz)  # one tree for the sweep and every score below
    search = search_yaw(
        target.xyz,
        source.xyz,
        params.trunk,
        SubReporter(reporter, 0, 0.6, "search"),
        target_tree=tree,
        threads=threads,
    )
    log.info("Trunk heading search kept %d heading(s)", len(search.solutions))
    # Rank the kept headings by a quick fine registration, then refine the best one
    # and its close contenders with the full settings (the rest stay as the quick
    # pass left them).
    choice = params.trunk.fine_points
    tries = ("all", "leaf") if choice == "best" else (choice,)
    quick = replace(
        params,
        fine=replace(
            params.fine,
            points=tries[0],
            voxel_size_m=params.trunk.refine_voxel_m,
            max_iterations=params.trunk.refine_iterations,
        ),
    )
    refined, used = [], []
    n = len(search.solutions)
    for k, sol in enumerate(search.solutions):
        step = SubReporter(reporter, 0.6 + 0.3 * k / n, 0.6 + 0.3 * (k + 1) / n)
        refined.append(
            refine(
                target, source, sol.T_target_source, quick, step, threads=threads
            ).T_target_source
        )
        used.append(tries[0])
        step.progress(1.0, "refining the best headings")
    done: dict[int, FineResult] = {}  # heading index -> its full fine fit
    if refined:
        # The best quick fit, and every heading whose quick fit comes close to it,
        # gets the full fine registration (on each point set tried); then the
        # close-point share decides, so a quick fit that stopped short never settles
        # a close race.
        close = _precise(refined, tree, source, params)
        contenders = trunk_contenders(
            close, params.trunk.contender_share, refined, source.xyz.mean(axis=0)
        )
        runs = [(k, points) for k in contenders for points in tries]
        fits = []
        for i, (k, points) in enumerate(runs):
            fits.append(
                refine(
                    target,
                    source,
                    refined[k],
                    replace(params, fine=replace(params.fine, points=points)),
                    SubReporter(
                        reporter,
                        0.9 + 0.1 * i / len(runs),
                        0.9 + 0.1 * (i + 1) / len(runs),
                    ),
                    threads=threads,
                )
            )
        scores = _precise([f.T_target_source for f in fits], tree, source, params)
        for j, k in enumerate(contenders):  # runs hold each contender's tries in turn
            pick = max(
                range(j * len(tries), (j + 1) * len(tries)), key=scores.__getitem__
            )
            refined[k], used[k] = fits[pick].T_target_source, runs[pick][1]
            done[k] = fits[pick]
    first_id = 1 + max((c.id for c in ranked.candidates), default=0)
    merged = merge_trunk_solutions(
        ranked,
        search,
        refined,
        target_tree=tree,
        source_xyz=source.xyz,
        params=params.coarse,
        precise_dist_m=params.trunk.score_dist_m,
        fine_points=used,
    )
    # These headings already had their full fine registration: register() reuses it.
    # Heading k became the candidate with id first_id + k (merge_trunk_solutions).
    finished = {first_id + k: fit for k, fit in done.items()}
    return merged, finished


def _precise(
    transforms: list[Transform],
    target_tree: cKDTree,
    source: ScanAnalysis,
    params: RegistrationParams,
) -> np.ndarray:
    """Share of sampled source points within trunk.score_dist_m under each transform."""
    return score_transforms(
        transforms, target_tree, source.xyz, params.coarse, params.trunk.score_dist_m
    )[1]
