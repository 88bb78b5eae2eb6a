"""The app's state records: one per scan (keyed by a scan id) and one per link.

A *scan* is one loaded file and what was computed on it alone (the per-scan steps of
the step table). A *link* is a target/source pair of scans and the review of its
candidates. The app holds two scans and one link, the roles "target" and "source"
naming the scan ids; more scans would add entries, not fields. No Qt.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from pathlib import Path

    import numpy as np

    from amrst.pipeline import ScanAnalysis
    from amrst.stages.candidates import Candidate
    from amrst.types import Cloud

ScanId = str  # stable for a loaded file: swapping roles does not change it
LinkId = tuple[ScanId, ScanId]  # (target scan id, source scan id)


@dataclass(slots=True)
class ScanState:
    """One loaded scan and its per-scan results."""

    id: ScanId
    path: Path | None = None
    cloud: Cloud | None = None
    analysis: ScanAnalysis | None = None  # separation, then skeleton and key points


@dataclass(slots=True)
class LinkReview:
    """The review of one link, kept by pose so it survives every re-run.

    Attributes
    ----------
    rejected_poses : tuple of (4, 4) arrays
        Poses the technician rejected; a new candidate at one of them starts rejected.
    manual : tuple of Candidate
        Manual poses, newest first, scored again after each Match.
    manual_labels : dict
        How each manual candidate was made, by candidate id.
    manual_next : int
        The last manual candidate number used.
    accepted_pose : (4, 4) array or None
        The pose accepted last (logged when a re-run finds it again).
    """

    rejected_poses: tuple[np.ndarray, ...] = ()
    manual: tuple[Candidate, ...] = ()
    manual_labels: dict[int, str] = field(default_factory=dict)
    manual_next: int = 0
    accepted_pose: np.ndarray | None = None
