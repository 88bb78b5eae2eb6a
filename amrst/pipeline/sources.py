"""The candidate sources beyond the tetrahedra, in the order ``find_matches`` asks them.

Every source adds its candidates to the ONE ranked list that the tetrahedron matches
start, scored by the same verification, each candidate naming its ``Origin``. A
source says when it is wanted (the trunk search only when nothing verifies) and
hands back the full fine fits it already made, by candidate id, so they are not run
twice.

To add a source: write ``wanted(ranked, params, centre) -> bool`` and
``add(ranked, target, source, params, reporter) -> (CandidateList, {id: FineResult})``
in a module of this package, give its candidates a new ``Origin``, and append a
``CandidateSource`` to ``CANDIDATE_SOURCES``.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

from amrst.pipeline.trunk_fallback import add_trunk_solutions, wants_trunk_search
from amrst.stages.coarse import Origin

if TYPE_CHECKING:
    from collections.abc import Callable

    import numpy as np

    from amrst.params import RegistrationParams
    from amrst.pipeline.analysis import ScanAnalysis
    from amrst.progress import Reporter
    from amrst.stages.coarse import CandidateList
    from amrst.stages.fine import FineResult


@dataclass(frozen=True, slots=True)
class CandidateSource:
    """One source of candidate solutions besides the tetrahedron matches."""

    origin: Origin
    label: str  # progress label
    timing_key: str  # key in MatchResult.timings
    wanted: Callable[[CandidateList, RegistrationParams, np.ndarray], bool]
    add: Callable[
        [CandidateList, ScanAnalysis, ScanAnalysis, RegistrationParams, Reporter],
        tuple[CandidateList, dict[int, FineResult]],
    ]


CANDIDATE_SOURCES: tuple[CandidateSource, ...] = (
    CandidateSource(
        Origin.TRUNK, "trunk", "trunk", wants_trunk_search, add_trunk_solutions
    ),
)
