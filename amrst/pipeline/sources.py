"""The candidate sources beyond the tetrahedra, in the order ``find_matches`` asks them.

Every source adds its candidates to the ONE ranked list that the tetrahedron matches
start, scored by the same verification, each candidate naming its ``Origin``. A
source says when it is wanted (the trunk search only when nothing verifies) and
hands back the full fine fits it already made, by candidate id, so they are not run
twice.

To add a source: write ``wanted(ranked, params, centre) -> bool`` and
``add(ranked, target, source, params, reporter, threads) -> (CandidateList,
{id: FineResult})`` in a module of this package, give its candidates a new ``Origin``,
and append a ``CandidateSource`` to ``CANDIDATE_SOURCES``.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import TYPE_CHECKING

from amrst.pipeline.features_source import add_feature_solution, wants_features
from amrst.pipeline.trunk_fallback import add_trunk_solutions, wants_trunk_search
from amrst.stages.candidates import CandidateList, Origin, distinct_solutions

if TYPE_CHECKING:
    from collections.abc import Callable

    import numpy as np

    from amrst.params import RegistrationParams
    from amrst.pipeline.analysis import ScanAnalysis
    from amrst.progress import Reporter
    from amrst.stages.candidates import Candidate
    from amrst.stages.fine import FineResult


@dataclass(frozen=True, slots=True)
class CandidateSource:
    """One source of candidate solutions besides the tetrahedron matches."""

    origin: Origin
    label: str  # progress label
    timing_key: str  # key in MatchResult.timings
    wanted: Callable[[CandidateList, RegistrationParams, np.ndarray], bool]
    # add(ranked, target, source, params, reporter, threads): the merged list and
    # {candidate id: FineResult} of the candidates already fully refined.
    add: Callable[
        [CandidateList, ScanAnalysis, ScanAnalysis, RegistrationParams, Reporter, int],
        tuple[CandidateList, dict[int, FineResult]],
    ]


# The feature matcher first: it costs less than the trunk search, which is not needed
# when the feature matcher's pose verifies.
CANDIDATE_SOURCES: tuple[CandidateSource, ...] = (
    CandidateSource(
        Origin.FEATURES,
        "feature matcher",
        "features",
        wants_features,
        add_feature_solution,
    ),
    CandidateSource(
        Origin.TRUNK, "trunk", "trunk", wants_trunk_search, add_trunk_solutions
    ),
)


def merge_same_solutions(ranked: CandidateList, centre: np.ndarray) -> CandidateList:
    """Fold a candidate into a better-ranked one of another origin with the same pose.

    A solution found by two sources is one candidate naming both (``also_found_by``);
    the better-ranked row keeps its transform, scores and id.
    """
    kept: list[Candidate] = []
    # Each kept candidate's origins, and per origin the kept rows that lack it: a
    # candidate is compared with those rows alone (with the tetrahedron matches
    # alone, none), so the list is not compared pair by pair.
    lacking: dict[Origin, list[int]] = {}
    for c in ranked.candidates:
        for k in lacking.get(c.origin, ()):
            done = kept[k]
            if c.origin not in done.origins and not distinct_solutions(
                c.T_target_source, done.T_target_source, centre
            ):
                kept[k] = replace(done, also_found_by=(*done.also_found_by, *c.origins))
                break
        else:
            kept.append(c)
            for origin in Origin:
                if origin not in c.origins:
                    lacking.setdefault(origin, []).append(len(kept) - 1)
    kept = [
        c if c.rank == r else replace(c, rank=r) for r, c in enumerate(kept, start=1)
    ]
    return CandidateList(tuple(kept), ranked.n_matches)
