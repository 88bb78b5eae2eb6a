"""register_scans: several scans of one tree onto a reference scan.

1. every scan is analysed once (prepare_scan, skeletonise_scan);
2. every pair is registered and verified (a *link*, see :mod:`amrst.multiscan.graph`);
3. a spanning tree of the best verified links says how each scan reaches the
   reference (its *path*);
4. all poses are refined together (:mod:`amrst.multiscan.joint`).

Two scans are the special case: :func:`register_scans` then runs
:func:`amrst.pipeline.register` itself, and the result is exactly the pair's result.
"""

from __future__ import annotations

import itertools
import time
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import numpy as np

from amrst.errors import InvalidInput
from amrst.multiscan.graph import Link, loop_closures, register_links, spanning_tree
from amrst.multiscan.joint import JointResult, refine_jointly
from amrst.neighbours import THREADS
from amrst.progress import NULL_REPORTER, Reporter, SubReporter
from amrst.stages.scene import stem_counts
from amrst.types import Cloud, Transform, world_transform

if TYPE_CHECKING:
    from collections.abc import Sequence

    from amrst.measure import TreeMeasures
    from amrst.params import RegistrationParams
    from amrst.pipeline import RegistrationResult


@dataclass(frozen=True, eq=False)
class MultiScanResult:
    """Every scan's pose on the reference, every link, and how each scan got there.

    Attributes
    ----------
    scans : tuple of Cloud
        The scans as given.
    reference : int
    T_reference_scan : tuple of (4, 4) float64 or None
        World frame: maps scan k's world coordinates into the reference's world
        coordinates (identity for the reference; None when scan k is not reached).
    T_tree : tuple of (4, 4) float64 or None
        The same, composed along the spanning tree before the joint refinement.
    links : tuple of Link
        Every pair, with its state, score and whether the tree uses it.
    paths : tuple of (tuple of int) or None
        Scans from the reference to scan k along the tree.
    joint : JointResult or None
        None for two scans (no joint step) or when at most one scan was reached.
    pair : RegistrationResult or None
        For two scans, the ``amrst.register`` result itself.
    loops : dict
        ``"i-j"`` -> disagreement (m) of verified links left out of the tree.
    tree : dict
        ``{"merged": TreeMeasures}`` of all reached scans together: the reference's
        tree of interest.
    stems : tuple of int
        The stems the scene stage found in each scan (many: a plot, not one tree).
    """

    scans: tuple[Cloud, ...]
    reference: int
    T_reference_scan: tuple[Transform | None, ...]
    T_tree: tuple[Transform | None, ...]
    links: tuple[Link, ...]
    paths: tuple[tuple[int, ...] | None, ...]
    joint: JointResult | None
    pair: RegistrationResult | None
    loops: dict[str, float]
    tree: dict[str, TreeMeasures]
    timings: dict[str, float]
    params: RegistrationParams
    origins: tuple[tuple[float, float, float] | None, ...] = field(default=())
    stems: tuple[int, ...] = field(default=())

    @property
    def reached(self) -> tuple[bool, ...]:
        """Whether each scan is placed on the reference."""
        return tuple(T is not None for T in self.T_reference_scan)

    @property
    def status(self) -> str:
        """``registered``, ``needs review`` or ``failed`` (amrst.review.verdict).

        Two scans: the pair's own verdict. More: from which scans reach the reference
        through verified links (:func:`amrst.review.verdict.scans_status`), and needs
        review when a link of the tree does (its fine registration did not converge).
        """
        from amrst.review.verdict import (
            NEEDS_REVIEW,
            REGISTERED,
            judge_result,
            scans_status,
        )

        if self.pair is not None:
            return judge_result(self.pair, self.params).status
        verified = {(ln.target, ln.source) for ln in self.links if ln.verified}
        verified |= {(b, a) for a, b in verified}
        by_verified_links = [
            path is not None
            and all(step in verified for step in itertools.pairwise(path))
            for path in self.paths
        ]
        status = scans_status(by_verified_links, self.confidence)
        unsure = any(ln.in_tree and ln.status != REGISTERED for ln in self.links)
        return NEEDS_REVIEW if status == REGISTERED and unsure else status

    @property
    def confidence(self) -> float:
        """The weakest confidence among the links of the tree (0 when none)."""
        used = [link.confidence for link in self.links if link.in_tree]
        return float(min(used)) if used else 0.0


def _check_inputs(scans: Sequence[Cloud], reference: int) -> None:
    if len(scans) < 2:
        raise InvalidInput(
            f"register_scans needs at least 2 scans, got {len(scans)}. Give the "
            "reference scan and the scans to move onto it."
        )
    if not 0 <= reference < len(scans):
        raise InvalidInput(
            f"reference={reference} is not a scan number: choose 0 to {len(scans) - 1}."
        )


def _origin(cloud: Cloud) -> tuple[float, float, float] | None:
    """Where the scanner stood in the cloud's world frame, when the file says."""
    value: Any = cloud.meta.get("scanner_origin")
    if value is None or len(value) != 3:
        return None
    return (float(value[0]), float(value[1]), float(value[2]))


def _from_pair(
    scans: tuple[Cloud, ...], reference: int, result: RegistrationResult
) -> MultiScanResult:
    other = 1 - reference
    m = result.metrics_fine
    link = Link(
        target=reference,
        source=other,
        verdict="verified" if result.coarse.verified else "unverified",
        score=float(result.coarse.candidate.score),
        confidence=float(result.confidence),
        weight=float(result.coarse.candidate.score) * float(m.overlap_fraction),
        T_local=result.fine.T_target_source,
        metrics=m,
        message=result.message,
        origin=str(result.coarse.candidate.origin),
        in_tree=True,
        seconds=float(result.timings.get("total", 0.0)),
        fine_converged=result.fine.converged,
    )
    poses: list[Transform | None] = [None, None]
    poses[reference] = np.eye(4)
    poses[other] = result.T_target_source
    paths: list[tuple[int, ...] | None] = [None, None]
    paths[reference], paths[other] = (reference,), (reference, other)
    return MultiScanResult(
        scans=scans,
        reference=reference,
        T_reference_scan=tuple(poses),
        T_tree=tuple(poses),
        links=(link,),
        paths=tuple(paths),
        joint=None,
        pair=result,
        loops={},
        tree={"merged": result.tree["merged"]} if "merged" in result.tree else {},
        timings=dict(result.timings),
        params=result.params,
        origins=tuple(_origin(c) for c in scans),
        stems=stem_counts(
            a.scene
            for a in [result.target, result.source][:: 1 if reference == 0 else -1]
        ),
    )


def register_scans(
    scans: Sequence[Cloud],
    reference: int = 0,
    params: RegistrationParams | None = None,
    reporter: Reporter | None = None,
    *,
    threads: int = THREADS,
) -> MultiScanResult:
    """Register several scans of one tree onto the reference scan.

    Parameters
    ----------
    scans : sequence of Cloud
        Two or more scans of one tree.
    reference : int
        Index of the scan the others are moved onto.
    params : RegistrationParams or None
        The two-scan engine's settings, used for every link.
    reporter : Reporter or None
    threads : int
        Threads for a pair's two analyses and for each KD-tree query; the result is
        the same for any number.

    Returns
    -------
    MultiScanResult

    Raises
    ------
    InvalidInput
        Fewer than two scans or a reference out of range.
    Cancelled
        When the reporter asks to stop.
    """
    from amrst.measure import measure_tree
    from amrst.params import RegistrationParams
    from amrst.pipeline import prepare_scan, register, skeletonise_scan
    from amrst.sampling import MEASURE_MAX_POINTS, reference_tree_sample

    scans = tuple(scans)
    _check_inputs(scans, reference)
    params = params or RegistrationParams()
    reporter = reporter or NULL_REPORTER
    if len(scans) == 2:
        result = register(
            scans[reference], scans[1 - reference], params, reporter, threads=threads
        )
        return _from_pair(scans, reference, result)
    t_start = time.perf_counter()
    timings: dict[str, float] = {}
    analyses = []
    for k, cloud in enumerate(scans):
        rep = SubReporter(reporter, 0.3 * k / len(scans), 0.3 * (k + 1) / len(scans))
        an = prepare_scan(
            cloud, params, SubReporter(rep, 0.0, 0.7, f"scan {k}"), threads=threads
        )
        analyses.append(
            skeletonise_scan(an, params, SubReporter(rep, 0.7, 1.0), threads=threads)
        )
    timings["analyse"] = time.perf_counter() - t_start
    t0 = time.perf_counter()
    links = register_links(
        analyses,
        reference,
        params,
        SubReporter(reporter, 0.3, 0.85, "links"),
        threads=threads,
    )
    timings["links"] = time.perf_counter() - t0
    graph = spanning_tree(links, len(scans), reference)
    t0 = time.perf_counter()
    joint_result = None
    poses = graph.poses
    if sum(p is not None for p in poses) > 2:
        joint_result = refine_jointly(
            analyses,
            poses,
            reference,
            params,
            SubReporter(reporter, 0.85, 0.95),
            threads=threads,
        )
        poses = joint_result.poses
    timings["joint"] = time.perf_counter() - t0

    def world(pose: Transform | None, k: int) -> Transform | None:
        if pose is None:
            return None
        return world_transform(pose, scans[reference], scans[k])

    t0 = time.perf_counter()
    T_world = tuple(world(p, k) for k, p in enumerate(poses))
    # The reference's tree of interest in each scan, as a pair measures it.
    merged, size = [], 0
    ref = (scans[reference], analyses[reference])
    for k, T in enumerate(T_world):
        if T is not None:
            part, n = reference_tree_sample(
                scans[k], analyses[k], ref, T, MEASURE_MAX_POINTS, seed=k
            )
            merged.append(part.world_xyz @ T[:3, :3].T + T[:3, 3])
            size += n
    tree = {"merged": measure_tree(np.vstack(merged), params.measure, reporter, size)}
    timings["measure"] = time.perf_counter() - t0
    timings["total"] = time.perf_counter() - t_start
    reporter.progress(1.0, "done")
    return MultiScanResult(
        scans=scans,
        reference=reference,
        T_reference_scan=T_world,
        T_tree=tuple(world(p, k) for k, p in enumerate(graph.poses)),
        links=graph.links,
        paths=graph.paths,
        joint=joint_result,
        pair=None,
        loops=loop_closures(graph.links, graph.poses),
        tree=tree,
        timings=timings,
        params=params,
        origins=tuple(_origin(c) for c in scans),
        stems=stem_counts(a.scene for a in analyses),
    )
