"""Registration of a plot's scans by their stem maps.

Each scan is analysed once: preprocessed (the points every candidate is verified on
and the fine registration uses; the scene stage is not needed, the stem map finds the
ground and every stem itself) and its stem map made. Each pair of scans is a *link*:
the stem poses (``match.py``) are verified as the technician's manual poses are
(``review.manual.ManualScorer``: the short polish and the tight score), on a sample of
the source's points above its ground, and the best verified one is fine-registered
(``pipeline.refine``). Scans far apart share too little surface for that score to
judge; a pose held by four or more stems with no rival as well held
(``match.held_by_stems``) is taken then, as needing review when those stems fix its
heading loosely (``match.HELD_HEADING_SD_DEG``). When no stem pose holds, the
two-scan engine runs as the fallback (tetrahedra, feature matcher, trunk search). A
link the technician gives as point pairs is taken from them instead
(:func:`register_plot_link_by_hand`), and one they leave out (a link they found wrong,
so that the scans are joined through others) is not registered. The links then form
the multiscan spanning tree, and a joint refinement is kept when it lowers the error
(``amrst.multiscan``).
"""

from __future__ import annotations

import time
from dataclasses import dataclass, replace
from typing import TYPE_CHECKING

import numpy as np

from amrst.errors import InvalidInput
from amrst.multiscan.graph import (
    Link,
    link_pairs,
    loop_closures,
    loop_confirmed,
    not_converged,
    scan_doubts,
    scan_statuses,
    spanning_tree,
)
from amrst.multiscan.joint import JointResult, refine_jointly
from amrst.neighbours import THREADS
from amrst.plot.match import HELD_HEADING_SD_DEG, StemPose, held_by_stems, stem_poses
from amrst.plot.residual import Surfaces, bundle_error, scan_residuals
from amrst.plot.stemmap import StemMap, StemMapParams, map_stems, which_way_up
from amrst.progress import NULL_REPORTER, Reporter, SubReporter
from amrst.stages.candidates import (
    Candidate,
    CandidateList,
    CoarseResult,
    Origin,
    choose_coarse,
)

if TYPE_CHECKING:
    from collections.abc import Collection, Mapping, Sequence

    from amrst.params import RegistrationParams
    from amrst.pipeline import ScanAnalysis
    from amrst.review.manual import ManualScorer
    from amrst.types import Cloud, Transform

#: Origin named by the links the stem map registered.
STEMS_ORIGIN = Origin.STEMS.value
#: Origin named by the links placed from the technician's point pairs.
HAND_ORIGIN = Origin.MANUAL.value
#: Origin named by the links the technician left out.
LEFT_OUT_ORIGIN = "left out"
#: The fine registration of a plot link: source points, first correspondence
#: distance (m) and scales down to the usual last one.
PLOT_FINE_POINTS = 20_000
PLOT_FINE_REACH_M = 0.2
PLOT_FINE_SCALES = 4
#: A stem pose whose stems meet loosely is refined from a first reach of this many
#: times their RMS (up to ``PLOT_FINE_REACH_MAX_M``): the pose can be that far off
#: at the plot's edge, out of the usual reach.
REACH_PER_STEM_RMS = 3.0
PLOT_FINE_REACH_MAX_M = 0.5
#: A stem pose is scored on the source points at least this high above its ground.
SCORE_ABOVE_GROUND_M = 0.5


@dataclass(frozen=True, slots=True)
class PlotScan:
    """One scan of the plot, analysed once: preprocessed points and stem map.

    ``analysis.cloud`` is the scan as the plot keeps it: the stem map's working points
    (``stemmap.working_index``, with their attributes), not every point read, so
    that a run holds one scan as read at a time. ``points_read`` counts the points the
    scan had; ``file_stamp`` is its file's size and modification time when it was read
    (None: not read from a file), so that the file is known unchanged when read again.
    """

    analysis: ScanAnalysis
    stems: StemMap
    points_read: int
    seconds: float  # to analyse it
    file_stamp: tuple[int, int] | None = None
    read_seconds: float = 0.0  # to read its file (0: given in memory)


@dataclass(frozen=True, slots=True)
class PlotLink:
    """A link, the stems it shares, and its residual.

    ``shared``: (target stem, source stem) pairs, empty when none; ``residual_m``: the
    source's distance to the target's surfaces at the link's pose
    (``residual.Surfaces``; NaN when failed).
    """

    link: Link
    shared: np.ndarray
    residual_m: float = float("nan")


@dataclass(frozen=True, slots=True)
class PlotRegistration:
    """Every scan's pose on the reference (local frames), the links and the bundle.

    ``poses[k]`` maps scan k's local coordinates into the reference's (None: not
    reached); ``residuals_m[k]`` is scan k's distance to the surfaces of the others
    where they overlap (``residual.scan_residuals``, NaN when not placed) and
    ``bundle_rmse_m`` their RMS, at the final poses (after the joint refinement when
    it did not raise the bundle error; ``joint`` is None for two scans, whose link is
    already their fine fit).
    ``statuses[k]`` is scan k's state: registered, needs review or failed
    (:func:`amrst.multiscan.graph.scan_statuses`); ``turned[k]``, for a scan that
    failed, how it seems to stand when another way up holds far more ground
    (:func:`amrst.plot.stemmap.which_way_up`; "" else).
    """

    scans: tuple[PlotScan, ...]
    reference: int
    poses: tuple[Transform | None, ...]
    links: tuple[PlotLink, ...]
    paths: tuple[tuple[int, ...] | None, ...]
    joint: JointResult | None
    loops: dict[str, float]
    statuses: tuple[str, ...]
    turned: tuple[str, ...]
    residuals_m: tuple[float, ...]
    bundle_rmse_m: float
    timings: dict[str, float]

    def loop_confirms(self, link: Link) -> bool:
        """Tell whether a loop of links confirms ``link``, whatever its own state.

        Derived from the links, paths and loops (``graph.loop_confirmed``).
        """
        confirmed = loop_confirmed(self._links(), self.paths, self.loops)
        return frozenset((link.target, link.source)) in confirmed

    def doubts(self) -> tuple[frozenset[tuple[int, int]] | None, ...]:
        """Per scan, the unsure links its pose rests on (``graph.scan_doubts``)."""
        return scan_doubts(self._links(), self.paths, self.loops)

    def accepted(
        self, review: Mapping[tuple[int, int], Transform]
    ) -> set[tuple[int, int]]:
        """Return the links the technician accepted, at the pose they have."""
        from amrst.plot.review import holding

        clouds = [scan.analysis.cloud for scan in self.scans]
        return holding(
            review,
            (
                (key, status, T, clouds[key[1]].offset)
                for key, (status, T) in self.link_states().items()
            ),
        )

    def link_states(self) -> dict[tuple[int, int], tuple[str, Transform | None]]:
        """Each link's status (registered when a loop confirms it) and world pose."""
        from amrst.review.verdict import REGISTERED
        from amrst.types import world_transform

        clouds = [scan.analysis.cloud for scan in self.scans]
        return {
            (ln.target, ln.source): (
                REGISTERED if self.loop_confirms(ln) else ln.status,
                None
                if ln.T_local is None
                else world_transform(ln.T_local, clouds[ln.target], clouds[ln.source]),
            )
            for ln in self._links()
        }

    def to_accept(
        self, checked: Mapping[tuple[int, int], Transform]
    ) -> tuple[dict[tuple[int, int], Transform], list[str]]:
        """Return the checked links to accept, at the poses checked, and notes.

        ``checked``: links (in their own order) and the world poses the technician
        checked. A link is accepted when it needs review and its pose now is the one
        checked (``review.still_holds``); a note says why of each other one.
        """
        from amrst.review.verdict import FAILED, NEEDS_REVIEW

        states = self.link_states()
        holds = self.accepted(checked)
        poses, notes = {}, []
        for (i, j), T in sorted(checked.items()):
            status = states[i, j][0]
            name = f"the link of scans {i + 1} and {j + 1}"
            if (i, j) in holds:
                poses[i, j] = T
            elif status == NEEDS_REVIEW:
                notes.append(
                    f"{name} moved since the run you checked: check it again, then "
                    "--accept it"
                )
            elif status == FAILED:
                notes.append(f"{name} failed at this run: nothing to accept")
            else:
                notes.append(f"{name} is {status}: nothing to accept")
        return poses, notes

    def states(self, review: Mapping[tuple[int, int], Transform]) -> tuple[str, ...]:
        """Each scan's state with the accepted links ``review`` holds (its status else)."""
        from amrst.plot.review import scan_state

        keep = self.accepted(review)
        return tuple(
            scan_state(s, d, keep)
            for s, d in zip(self.statuses, self.doubts(), strict=True)
        )

    def _links(self) -> list[Link]:
        return [pl.link for pl in self.links]


def plot_params() -> RegistrationParams:
    """Return the registration settings of a plot: no scene stage, fine on all points.

    Neither the scene stage nor the wood-leaf separation is needed: the stem map
    finds the ground and every stem itself. The fine registration uses all points,
    more of them than for one tree (a few thousand points spread over a plot are
    mostly ground), from a first reach of 20 cm: stems that agree place a scan
    within centimetres, and a wider reach lets crowns, each scan seeing other sides
    of them, pull a right pose off by a tenth of a degree.
    """
    from amrst.params import RegistrationParams

    params = RegistrationParams()
    return replace(
        params,
        scene=replace(params.scene, mode="off"),
        separate=replace(params.separate, mode="all_wood"),
        fine=replace(
            params.fine,
            points="all",
            max_points=PLOT_FINE_POINTS,
            max_corr_dist_m=PLOT_FINE_REACH_M,
            scales=PLOT_FINE_SCALES,
        ),
    )


def analyse_plot_scan(
    cloud: Cloud,
    params: RegistrationParams,
    stem_params: StemMapParams,
    reporter: Reporter = NULL_REPORTER,
    *,
    threads: int = THREADS,
) -> PlotScan:
    """Preprocess one scan and make its stem map; keep its working points.

    ``params`` are :func:`plot_params`'s.
    """
    from amrst.pipeline import prepare_scan

    t0 = time.perf_counter()
    an = prepare_scan(
        cloud,
        params,
        SubReporter(reporter, 0.0, 0.5, "preprocess"),
        skeleton=False,
        threads=threads,
    )
    stems = map_stems(cloud.xyz, stem_params, reporter, trees=False)
    assert stems.index is not None  # map_stems gives the rows it kept
    # The stem map's own points: one copy of them, not two.
    attributes = {k: v[stems.index] for k, v in cloud.attributes.items()}
    kept = replace(cloud, xyz=stems.xyz, attributes=attributes)
    seconds = time.perf_counter() - t0
    return PlotScan(replace(an, cloud=kept), stems, len(cloud), seconds)


def analyse_plot(
    clouds: Sequence[Cloud],
    reporter: Reporter = NULL_REPORTER,
    *,
    threads: int = THREADS,
) -> tuple[PlotScan, ...]:
    """Analyse every scan of a plot with the plot's default settings."""
    params, stem_params = plot_params(), StemMapParams()
    n = len(clouds)
    return tuple(
        analyse_plot_scan(
            c,
            params,
            stem_params,
            SubReporter(reporter, k / n, (k + 1) / n, f"scan {k + 1}"),
            threads=threads,
        )
        for k, c in enumerate(clouds)
    )


def register_plot_link(
    target: PlotScan,
    source: PlotScan,
    indices: tuple[int, int],
    params: RegistrationParams,
    reporter: Reporter = NULL_REPORTER,
    *,
    threads: int = THREADS,
) -> PlotLink:
    """Register one pair by its stems; the two-scan engine when they do not verify."""
    from amrst.pipeline import evaluate, refine
    from amrst.review.manual import MANUAL_ID_BASE, ManualScorer

    t0 = time.perf_counter()
    poses = stem_poses(target.stems, source.stems)
    cands = []
    if poses:
        above = _above_ground(source, params)
        on = "above the ground " if len(above) < len(source.analysis.xyz) else ""
        scorer = ManualScorer(
            target.analysis.xyz, source.analysis.xyz, params.coarse, score_xyz=above
        )
    for k, pose in enumerate(poses):
        reporter.check_cancelled()
        label = f"pose of {len(pose.pairs)} stem pairs"
        cands.append(_score_stem_pose(scorer, pose, MANUAL_ID_BASE + k, label, on))
    cands.sort(key=lambda c: -c.score)
    ranked = CandidateList(
        tuple(replace(c, rank=r) for r, c in enumerate(cands, 1)), len(poses)
    )
    centre = np.r_[source.analysis.xyz[:, :2].mean(axis=0), 0.0]
    coarse = choose_coarse(ranked, frozenset(), centre) if cands else None
    held = held_by_stems(poses)
    if coarse is not None and coarse.verified and not _outvoted(coarse, held):
        won = poses[coarse.candidate.id - MANUAL_ID_BASE]
        start, confidence = coarse.T_target_source, coarse.confidence
        score = coarse.candidate.score
        # The pairs that made the pose; more stems may meet under the refined pose
        # (the link's shared stems).
        message = f"pose of {len(won.pairs)} stem pairs; {coarse.message}"
    elif held is not None:
        won = poses[held]
        # Stems that leave the heading loose (wide stems, each scan seeing another
        # side of them; stems close together) give a pose to check, not to trust.
        sure = won.heading_sd_deg <= HELD_HEADING_SD_DEG
        start, confidence = won.T_target_source, 1.0 if sure else 0.0
        score = next(c.score for c in cands if c.id == MANUAL_ID_BASE + held)
        message = (
            f"the {len(won.pairs)} stem pairs of the pose meet within "
            f"{100 * won.rms_m:.0f} cm and "
            f"no other pose is held by as many; the scans share too little surface "
            f"for the point score to judge ({score:.0%})"
        ) + (
            ""
            if sure
            else f"; but these stems fix its heading to ±{won.heading_sd_deg:.1f}° "
            "only: check it"
        )
    else:
        return _fallback(
            target, source, indices, params, reporter=reporter, threads=threads, t0=t0
        )
    reach = min(
        max(params.fine.max_corr_dist_m, REACH_PER_STEM_RMS * won.rms_m),
        PLOT_FINE_REACH_MAX_M,
    )
    fine = refine(
        target.analysis,
        source.analysis,
        start,
        replace(params, fine=replace(params.fine, max_corr_dist_m=reach)),
        SubReporter(reporter, 0.5, 0.95),
        threads=threads,
    )
    T = fine.T_target_source
    metrics = evaluate(target.analysis, source.analysis, T, params, threads=threads)
    link = Link(
        target=indices[0],
        source=indices[1],
        verdict="verified",
        score=float(score),
        confidence=float(confidence),
        weight=float(score) * float(metrics.overlap_fraction),
        T_local=T,
        metrics=metrics,
        message=message + not_converged(fine),
        origin=STEMS_ORIGIN,
        seconds=time.perf_counter() - t0,
        fine_converged=fine.converged,
    )
    return PlotLink(link, _shared(target.stems, source.stems, T))


def register_plot_link_by_hand(
    target: PlotScan,
    source: PlotScan,
    indices: tuple[int, int],
    pairs: tuple[np.ndarray, np.ndarray],
    params: RegistrationParams,
    reporter: Reporter = NULL_REPORTER,
    *,
    threads: int = THREADS,
) -> PlotLink:
    """Register one pair from point pairs the technician picked in both scans.

    ``pairs``: (target points, source points), each (K, 3) in the files' (world)
    coordinates. The pairs' pose is fine-registered as a stem pose is, and the result
    kept only where it fits the scans better (as for a pair). The link is used
    whatever it shows; it is *registered* when, where both scans saw the plot, it
    shows what a right pose shows, else *needs review* with the reason.

    Raises
    ------
    InvalidInput
        Pairs that cannot fix a pose.
    """
    from amrst.pipeline import evaluate, refine
    from amrst.review.manual import MANUAL_ID_BASE, ManualScorer, fit_pairs, weak_turn
    from amrst.review.manual_keep import keep_manual
    from amrst.review.overlap import overlap_distances
    from amrst.review.strength import axis_strength
    from amrst.review.verdict import REGISTERED, manual_verdict

    t0 = time.perf_counter()
    tgt, src = target.analysis, source.analysis
    t_pts = np.asarray(pairs[0], float) - tgt.cloud.offset
    s_pts = np.asarray(pairs[1], float) - src.cloud.offset
    start = fit_pairs(t_pts, s_pts).T_target_source
    if not np.all(np.isfinite(start)):
        raise InvalidInput(
            f"The point pairs of scans {indices[0] + 1} and {indices[1] + 1} do not "
            "fix a pose: pick them farther apart."
        )
    fine = refine(tgt, src, start, params, reporter, threads=threads)
    scorer = ManualScorer(tgt.xyz, src.xyz, params.coarse)
    fine, _ = keep_manual(
        fine, start, tgt.xyz, src.xyz, params.coarse, tree=scorer.tree
    )
    T = fine.T_target_source
    # Against the stem map's points (1 cm voxel): the preprocessed points of a big
    # scan are thinned to a 10 cm voxel, too coarse to show a right pose's distances.
    verdict = manual_verdict(
        overlap_distances(target.stems.xyz, src.xyz, T),
        axis_strength(tgt.xyz, src.xyz, T, params.metrics.overlap_dist_m),
        f"Your {len(t_pts)} point pairs",
    )
    score = scorer.score(T, MANUAL_ID_BASE, "point pairs").score
    metrics = evaluate(tgt, src, T, params, threads=threads)
    swapped = ""
    if verdict.status != REGISTERED and _fits_swapped(target, source, pairs, params):
        i, j = indices[0] + 1, indices[1] + 1
        swapped = (
            f"Read the other way round, scan {j}'s points first, the pairs fit: the "
            f"file's target and source columns are swapped (give it as --pairs {j} {i})."
        )
    link = Link(
        target=indices[0],
        source=indices[1],
        verdict="verified",
        score=float(score),
        confidence=1.0 if verdict.status == REGISTERED else 0.0,
        weight=float(score) * float(metrics.overlap_fraction),
        T_local=T,
        metrics=metrics,
        message=" ".join(filter(None, (verdict.reason, weak_turn(t_pts), swapped))),
        origin=HAND_ORIGIN,
        seconds=time.perf_counter() - t0,
    )
    return PlotLink(link, _shared(target.stems, source.stems, T))


def _fits_swapped(
    target: PlotScan,
    source: PlotScan,
    pairs: tuple[np.ndarray, np.ndarray],
    params: RegistrationParams,
) -> bool:
    """Tell whether the pairs fit the two scans read the other way round.

    That is, each column of points picked in the other scan: the commonest slip in
    a pairs file.
    """
    from amrst.pipeline import refine
    from amrst.review.manual import fit_pairs
    from amrst.review.overlap import overlap_distances
    from amrst.review.strength import axis_strength
    from amrst.review.verdict import REGISTERED, manual_verdict

    tgt, src = target.analysis, source.analysis
    t_pts = np.asarray(pairs[1], float) - tgt.cloud.offset
    s_pts = np.asarray(pairs[0], float) - src.cloud.offset
    start = fit_pairs(t_pts, s_pts).T_target_source
    if not np.all(np.isfinite(start)):
        return False
    T = refine(tgt, src, start, params).T_target_source
    verdict = manual_verdict(
        overlap_distances(target.stems.xyz, src.xyz, T),
        axis_strength(tgt.xyz, src.xyz, T, params.metrics.overlap_dist_m),
        "",
    )
    return verdict.status == REGISTERED


def _score_stem_pose(
    scorer: ManualScorer, pose: StemPose, cand_id: int, label: str, on: str
) -> Candidate:
    """Score a stem pose polished or as given, whichever brings more points together.

    A stem pose is often right already, and the short polish, on a plot's thinned
    points (mostly ground), can move it off. Every stem pose is scored the same way,
    so all are marked ``polished``: each is the others' rival in the confidence.
    ``on``: which source points the scorer's sample is drawn from, for the text.
    """
    from amrst.review.manual import tight_share

    polished = scorer.score(pose.T_target_source, cand_id, label)
    given = tight_share(
        pose.T_target_source, scorer.tree, scorer.sample, scorer.params.tight_dist_m
    )
    T, score = polished.T_target_source, polished.score
    if given > score:
        T, score = pose.T_target_source, given
    how = (
        "as given"
        if np.array_equal(T, pose.T_target_source)
        else "after a short ICP polish"
    )
    return replace(
        polished,
        score=score,
        T_target_source=T,
        polished=True,
        explanation=f"Stem pose ({label}); {score:.0%} of the sampled source points "
        f"{on}lie within {scorer.params.tight_dist_m * 100:.0f} cm of the target "
        f"{how}.",
    )


def _above_ground(scan: PlotScan, params: RegistrationParams) -> np.ndarray:
    """Return the points of ``scan`` that tell one stem pose from another.

    Every stem pose is levelled on the ground, so the ground meets the ground at a
    wrong pose as well as at the right one: scored on all points, a pose turned half
    a turn can score nearly as well as the right one, and the short ICP polish,
    pulled by the ground's thinned points, drifts by an amount that depends on the
    file's frame. The trees above the ground meet only at the right pose. All
    points when fewer than a verification sample stand above the ground.
    """
    xyz = scan.analysis.xyz
    above = xyz[scan.stems.ground.height(xyz) > SCORE_ABOVE_GROUND_M]
    return above if len(above) >= params.coarse.verify_points else xyz


def _outvoted(coarse: CoarseResult, held: int | None) -> bool:
    """Tell whether the stems hold another pose than an unsure point-score winner.

    The point score of far-apart plot scans can rank a two-stem coincidence just
    above the pose four or more stems meet at; the stems settle what it cannot.
    """
    from amrst.review.manual import MANUAL_ID_BASE
    from amrst.review.verdict import LOW_CONFIDENCE

    return (
        held is not None
        and coarse.confidence < LOW_CONFIDENCE
        and coarse.candidate.id != MANUAL_ID_BASE + held
    )


def _fallback(
    target: PlotScan,
    source: PlotScan,
    indices: tuple[int, int],
    params: RegistrationParams,
    *,
    reporter: Reporter,
    threads: int,
    t0: float,
) -> PlotLink:
    """Register the pair with the two-scan engine (scene stage and separation on)."""
    from amrst.multiscan.graph import register_link
    from amrst.params import RegistrationParams
    from amrst.pipeline import prepare_scan, skeletonise_scan

    default = RegistrationParams()
    full = replace(params, scene=default.scene, separate=default.separate)
    ans = []
    for scan in (target, source):
        an = prepare_scan(scan.analysis.cloud, full, reporter, threads=threads)
        ans.append(skeletonise_scan(an, full, reporter, threads=threads))
    link = register_link(ans[0], ans[1], indices, full, reporter, threads=threads)
    link = replace(
        link,
        message=f"by the two-scan engine, as no stem pose verified: {link.message}",
        seconds=time.perf_counter() - t0,
    )
    shared = (
        np.zeros((0, 2), np.int64)
        if link.T_local is None
        else _shared(target.stems, source.stems, link.T_local)
    )
    return PlotLink(link, shared)


def _shared(target: StemMap, source: StemMap, T: Transform) -> np.ndarray:
    """(K, 2) stems of the two scans that meet under the pose (within 0.3 m)."""
    tk, sk = target.keys(), source.keys()
    if not len(tk) or not len(sk):
        return np.zeros((0, 2), np.int64)
    moved = sk @ T[:3, :3].T + T[:3, 3]
    d = np.hypot(moved[:, None, 0] - tk[None, :, 0], moved[:, None, 1] - tk[None, :, 1])
    best = np.argmin(d, axis=1)
    ok = d[np.arange(len(sk)), best] <= 0.3
    return np.column_stack([best[ok], np.flatnonzero(ok)]).astype(np.int64)


def check_links(
    n: int,
    reference: int,
    by_hand: Mapping[tuple[int, int], tuple[np.ndarray, np.ndarray]],
    left_out: Collection[tuple[int, int]],
    accept: Collection[tuple[int, int]] = (),
) -> tuple[
    dict[tuple[int, int], tuple[np.ndarray, np.ndarray]],
    set[tuple[int, int]],
    set[tuple[int, int]],
]:
    """Check the technician's links of a plot of ``n`` scans; key them as the links.

    Returns the hand pairs, the left-out links and the links to accept in their
    links' (target, source) order.

    Raises
    ------
    InvalidInput
        Pairs, a left-out or an accepted link that is not one of the plot's, a link
        both given pairs and left out, or both accepted and left out, or point pairs
        that do not keep their distances.
    """
    from amrst.review.manual import pairs_disagree

    pairs = link_pairs(n, reference)
    hand = _oriented(by_hand, pairs, n)
    dropped = {_link_key(i, j, pairs, n) for i, j in left_out}
    if dropped & set(hand):
        i, j = min(dropped & set(hand))
        raise InvalidInput(
            f"The link of scans {i + 1} and {j + 1} is both given point pairs and left "
            "out: do one or the other."
        )
    for (i, j), (t_pts, s_pts) in sorted(hand.items()):
        if apart := pairs_disagree(t_pts, s_pts):
            raise InvalidInput(f"The point pairs of scans {i + 1} and {j + 1} {apart}.")
    taken = {_link_key(i, j, pairs, n) for i, j in accept}
    if dropped & taken:
        i, j = min(dropped & taken)
        raise InvalidInput(
            f"The link of scans {i + 1} and {j + 1} is both accepted and left out: do "
            "one or the other."
        )
    return hand, dropped, taken


def cut_off(n: int, reference: int, left_out: Collection[tuple[int, int]]) -> set[int]:
    """Return the scans no chain of links joins to the reference without ``left_out``.

    A run cannot place them; only point pairs can.
    """
    import networkx as nx

    dropped = {frozenset(link) for link in left_out}
    graph = nx.Graph()
    graph.add_nodes_from(range(n))
    graph.add_edges_from(
        link for link in link_pairs(n, reference) if frozenset(link) not in dropped
    )
    reached: set[int] = nx.node_connected_component(graph, reference)
    return set(range(n)) - reached


def register_plot(
    scans: Sequence[PlotScan],
    reference: int = 0,
    reporter: Reporter = NULL_REPORTER,
    *,
    by_hand: Mapping[tuple[int, int], tuple[np.ndarray, np.ndarray]] | None = None,
    left_out: Collection[tuple[int, int]] = (),
    threads: int = THREADS,
) -> PlotRegistration:
    """Register the scans of a plot onto the reference scan.

    Parameters
    ----------
    scans : sequence of PlotScan
        Two or more scans of one plot, analysed (:func:`analyse_plot`).
    reference : int
    reporter : Reporter
    by_hand : mapping or None
        Point pairs that place a link instead of the automatic match:
        ``{(i, j): (points in scan i, the same points in scan j)}``, world
        coordinates, scan indices from 0.
    left_out : collection of (int, int)
        Links not to register (scan indices from 0, either order).
    threads : int

    Raises
    ------
    InvalidInput
        As :func:`check_links`.

    Returns
    -------
    PlotRegistration
    """
    from amrst.review.verdict import FAILED

    params = plot_params()
    n = len(scans)
    hand, dropped, _ = check_links(n, reference, by_hand or {}, left_out)
    pairs = link_pairs(n, reference)
    timings = {
        "read": sum(s.read_seconds for s in scans),
        "analyse": sum(s.seconds for s in scans),
    }
    t0 = t1 = time.perf_counter()
    links = []
    for m, (i, j) in enumerate(pairs):
        sub = SubReporter(
            reporter,
            0.85 * m / len(pairs),
            0.85 * (m + 1) / len(pairs),
            f"link {i + 1}-{j + 1}",
        )
        if (i, j) in dropped:
            link = _left_out(i, j)
        elif (i, j) in hand:
            link = register_plot_link_by_hand(
                scans[i], scans[j], (i, j), hand[i, j], params, sub, threads=threads
            )
        else:
            link = register_plot_link(
                scans[i], scans[j], (i, j), params, sub, threads=threads
            )
        links.append(link)
    timings["links"] = time.perf_counter() - t1
    graph = spanning_tree([pl.link for pl in links], n, reference)
    in_tree = {(ln.target, ln.source): ln for ln in graph.links}
    links = [replace(pl, link=in_tree[pl.link.target, pl.link.source]) for pl in links]
    t1 = time.perf_counter()
    analyses = [s.analysis for s in scans]
    surfaces = Surfaces([s.analysis.cloud.xyz for s in scans], threads)
    joint = None
    poses = graph.poses
    if sum(p is not None for p in poses) > 2:  # a pair's link is its fine fit
        # Kept when it does not raise the bundle error the plot reports; the judge's
        # residuals of the poses kept are the plot's (first: before, last: after).
        judged: list[tuple[float, ...]] = []

        def judge(p: Sequence[Transform | None]) -> float:
            judged.append(scan_residuals(surfaces, p))
            return bundle_error(judged[-1])

        joint = refine_jointly(
            analyses,
            graph.poses,
            reference,
            params,
            SubReporter(reporter, 0.85, 1.0, "joint refinement"),
            threads=threads,
            error=judge,
        )
        poses = joint.poses
        residuals = judged[-1] if joint.kept else judged[0]
    else:
        residuals = scan_residuals(surfaces, poses)
    links = [_with_residual(pl, surfaces) for pl in links]
    timings["joint"] = time.perf_counter() - t1
    timings["total"] = timings["read"] + timings["analyse"] + time.perf_counter() - t0
    loops = loop_closures(graph.links, graph.poses)
    statuses = scan_statuses(graph.links, graph.paths, loops)
    return PlotRegistration(
        scans=tuple(scans),
        reference=reference,
        poses=poses,
        links=tuple(links),
        paths=graph.paths,
        joint=joint,
        loops=loops,
        statuses=statuses,
        # Why a scan may have failed: it stands another way up.
        turned=tuple(
            which_way_up(scan.stems) if status == FAILED else ""
            for scan, status in zip(scans, statuses, strict=True)
        ),
        residuals_m=residuals,
        bundle_rmse_m=bundle_error(residuals),
        timings=timings,
    )


def _with_residual(pl: PlotLink, surfaces: Surfaces) -> PlotLink:
    T = pl.link.T_local
    if T is None:
        return pl
    return replace(
        pl, residual_m=surfaces.residual(pl.link.source, {pl.link.target: T})
    )


def _oriented(
    by_hand: Mapping[tuple[int, int], tuple[np.ndarray, np.ndarray]],
    pairs: Sequence[tuple[int, int]],
    n: int,
) -> dict[tuple[int, int], tuple[np.ndarray, np.ndarray]]:
    """Key the hand pairs by the links' own (target, source) order."""
    out = {}
    for (i, j), (t, s) in by_hand.items():
        key = _link_key(i, j, pairs, n)
        out[key] = (t, s) if key == (i, j) else (s, t)
    return out


def _link_key(
    i: int, j: int, pairs: Sequence[tuple[int, int]], n: int
) -> tuple[int, int]:
    """Return the link of scans i and j in its own (target, source) order.

    Raises
    ------
    InvalidInput
        No such link (a scan number out of range, or one scan twice).
    """
    if (i, j) in pairs:
        return i, j
    if (j, i) in pairs:
        return j, i
    if not (0 <= i < n and 0 <= j < n):
        missing = i if not 0 <= i < n else j
        raise InvalidInput(
            f"Scan {missing + 1} named for a link does not exist: the plot has scans "
            f"1 to {n}."
        )
    raise InvalidInput(
        f"Scan {i + 1} named twice for a link: name two different scans."
    )


def _left_out(i: int, j: int) -> PlotLink:
    link = Link(
        target=i,
        source=j,
        verdict="failed",
        score=0.0,
        confidence=0.0,
        weight=0.0,
        T_local=None,
        metrics=None,
        message="left out by you: not registered",
        origin=LEFT_OUT_ORIGIN,
    )
    return PlotLink(link, np.zeros((0, 2), np.int64))
