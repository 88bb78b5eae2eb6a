"""The link graph of a multi-scan tree: every pair registered, the best verified kept.

Each *link* is one pair of scans registered with the two-scan engine (find_matches,
coarse_from_matches, refine, evaluate) on analyses made once per scan. Links that
verify are weighted by their verification score times their overlap; a spanning tree
of the best of those (as Cyclone REGISTER 360 builds its link graph) says how each
scan reaches the reference: directly when its own link verified, else through the
scans it verified with. Poses along a path are composed in the reference's local frame.
"""

from __future__ import annotations

import itertools
import time
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np

from amrst.errors import RegistrationFailed
from amrst.neighbours import THREADS
from amrst.progress import NULL_REPORTER, Reporter, SubReporter
from amrst.review.verdict import FAILED, NEEDS_REVIEW, REGISTERED
from amrst.types import invert_transform

if TYPE_CHECKING:
    from collections.abc import Sequence

    from amrst.params import RegistrationParams
    from amrst.pipeline import ScanAnalysis
    from amrst.stages.fine import FineResult
    from amrst.stages.metrics import CloudMetrics
    from amrst.types import Transform


#: Cost of a weak link, in links: below 1, so one more link never beats a weaker one.
HOP_QUALITY = 0.5
#: A registered link left out of the tree that moves the source's points (at 10 m)
#: this far from where the tree's poses put them contradicts the tree (m).
LOOP_TOLERANCE_M = 0.25
#: A cycle of verified links that closes this well (m, at 10 m) confirms every link
#: on it: a wrong pose moves the points by far more (distinct candidates differ by
#: 3 deg, 50 cm at 10 m), and links matched pair by pair do not err alike.
LOOP_CONFIRM_M = 0.02


@dataclass(frozen=True, slots=True)
class Link:
    """One registered pair: ``source`` moved onto ``target`` (scan indices).

    Attributes
    ----------
    verdict : str
        What the candidate check gave, an internal word: ``verified``,
        ``unverified`` (a best guess that did not verify) or ``failed`` (no candidate
        at all; ``message`` says why). Files and messages say :attr:`status`.
    score : float
        Verification score of the chosen candidate, 0..1.
    weight : float
        ``score * overlap``: the spanning tree prefers heavy links.
    T_local : (4, 4) float64 or None
        Maps the source's local coordinates into the target's local coordinates.
    fine_converged : bool
        False when the fine registration stopped before it converged: the link
        needs review, as a pair whose fine registration did not converge does (its
        pose can lie between the right one and where it started).
    """

    target: int
    source: int
    verdict: str
    score: float
    confidence: float
    weight: float
    T_local: Transform | None
    metrics: CloudMetrics | None
    message: str
    origin: str = ""
    in_tree: bool = False
    seconds: float = 0.0
    fine_converged: bool = True

    @property
    def verified(self) -> bool:
        """True when the engine verified this link."""
        return self.verdict == "verified"

    @property
    def status(self) -> str:
        """``registered``, ``needs review`` or ``failed`` (amrst.review.verdict)."""
        from amrst.review.verdict import scans_status

        if self.verified and not self.fine_converged:
            return NEEDS_REVIEW
        return scans_status((True, self.verified), self.confidence)

    def as_dict(self) -> dict[str, object]:
        """Plain numbers for JSON (the transform as nested lists, local frames)."""
        return {
            "target": self.target,
            "source": self.source,
            "status": self.status,
            "verified": self.verified,
            "score": self.score,
            "confidence": self.confidence,
            "weight": self.weight,
            "in_tree": self.in_tree,
            "origin": self.origin,
            "message": self.message,
            "seconds": round(self.seconds, 4),
            "fine_converged": self.fine_converged,
            "metrics": None if self.metrics is None else self.metrics.as_dict(),
        }


@dataclass(frozen=True, slots=True)
class LinkGraph:
    """Every link, the spanning tree's paths and the composed poses.

    ``poses[k]`` maps scan k's local coordinates into the reference's local
    coordinates (None: scan k is not reached by verified links); ``paths[k]`` lists the
    scans from the reference to k.
    """

    links: tuple[Link, ...]
    paths: tuple[tuple[int, ...] | None, ...]
    poses: tuple[Transform | None, ...]
    timings: dict[str, float] = field(default_factory=dict)


def register_link(
    target: ScanAnalysis,
    source: ScanAnalysis,
    indices: tuple[int, int],
    params: RegistrationParams,
    reporter: Reporter = NULL_REPORTER,
    *,
    threads: int = THREADS,
) -> Link:
    """Register one pair with the two-scan engine and say how sure it is.

    ``threads``: for the KD-tree queries.
    """
    from amrst.pipeline import coarse_from_matches, evaluate, find_matches, refine

    t0 = time.perf_counter()
    try:
        matches = find_matches(
            target, source, params, SubReporter(reporter, 0.0, 0.7, ""), threads=threads
        )
        coarse = coarse_from_matches(matches)
    except RegistrationFailed as exc:
        return Link(*indices, "failed", 0.0, 0.0, 0.0, None, None, str(exc),
                    seconds=time.perf_counter() - t0)  # fmt: skip
    fine = refine(
        target,
        source,
        coarse,
        params,
        SubReporter(reporter, 0.7, 0.95),
        matches,
        threads=threads,
    )
    metrics = evaluate(target, source, fine.T_target_source, params, threads=threads)
    score = float(coarse.candidate.score)
    if not np.isfinite(score):
        score = 0.0
    return Link(
        target=indices[0],
        source=indices[1],
        verdict="verified" if coarse.verified else "unverified",
        score=score,
        confidence=float(coarse.confidence),
        weight=score * float(metrics.overlap_fraction),
        T_local=fine.T_target_source,
        metrics=metrics,
        message=coarse.message + not_converged(fine),
        origin=str(coarse.candidate.origin),
        seconds=time.perf_counter() - t0,
        fine_converged=fine.converged,
    )


def not_converged(fine: FineResult) -> str:
    """Return what a link's message adds when its fine registration did not converge."""
    if fine.converged:
        return ""
    return (
        f"; the fine registration did not converge after {fine.iterations} "
        "iterations: check the overlay"
    )


def link_pairs(n: int, reference: int) -> list[tuple[int, int]]:
    """Return every pair (target, source) once; the reference is always the target."""
    pairs = []
    for i in range(n):
        for j in range(i + 1, n):
            pairs.append((j, i) if j == reference else (i, j))
    return pairs


def register_links(
    analyses: Sequence[ScanAnalysis],
    reference: int,
    params: RegistrationParams,
    reporter: Reporter = NULL_REPORTER,
    *,
    threads: int = THREADS,
) -> list[Link]:
    """Register every pair of analysed scans (reference first in each of its pairs).

    ``threads``: for the KD-tree queries.
    """
    pairs = link_pairs(len(analyses), reference)
    links = []
    for k, (i, j) in enumerate(pairs):
        reporter.check_cancelled()
        step = SubReporter(
            reporter, k / len(pairs), (k + 1) / len(pairs), f"link {i}-{j}"
        )
        links.append(
            register_link(
                analyses[i], analyses[j], (i, j), params, step, threads=threads
            )
        )
    return links


def spanning_tree(links: Sequence[Link], n: int, reference: int) -> LinkGraph:
    """Keep the best verified links as a tree; compose each reached scan's pose.

    The tree is the shortest-path tree of the verified links from the reference:
    registered links before those that need review (a verified candidate whose
    runner-up scored almost as well is often the wrong one), then fewest links (every
    link adds its error), then the best ones (a link costs ``1 + HOP_QUALITY * (1 -
    weight)``, plus ``2 n`` when it needs review). A scan verified with the reference
    is therefore joined to it directly; the others go through the scans they verify
    with.

    Parameters
    ----------
    links : sequence of Link
    n : int
        Number of scans.
    reference : int

    Returns
    -------
    LinkGraph
        Links marked ``in_tree``, the path from the reference to each scan, and the
        pose of each reached scan in the reference's local frame.
    """
    import networkx as nx

    graph = nx.Graph()
    graph.add_nodes_from(range(n))
    for k, link in enumerate(links):
        if link.verified:
            cost = 1.0 + HOP_QUALITY * (1.0 - min(max(link.weight, 0.0), 1.0))
            if link.status != REGISTERED:
                cost += 2.0 * n  # more than any path of registered links
            graph.add_edge(link.target, link.source, cost=cost, link=k)
    reach = nx.single_source_dijkstra_path(graph, reference, weight="cost")
    chosen = {
        graph.edges[a, b]["link"]
        for path in reach.values()
        for a, b in itertools.pairwise(path)
    }
    marked = tuple(_with_tree(link, k in chosen) for k, link in enumerate(links))
    paths: list[tuple[int, ...] | None] = [None] * n
    poses: list[Transform | None] = [None] * n
    for k in range(n):
        if k not in reach:
            continue
        path = tuple(reach[k])
        paths[k] = path
        pose = np.eye(4)
        for a, b in itertools.pairwise(path):
            pose = pose @ _step(marked, a, b)
        poses[k] = pose
    return LinkGraph(marked, tuple(paths), tuple(poses))


def _with_tree(link: Link, in_tree: bool) -> Link:
    from dataclasses import replace

    return replace(link, in_tree=in_tree)


def _step(links: Sequence[Link], a: int, b: int) -> Transform:
    """Return the local transform a <- b from the link joining a and b."""
    for link in links:
        if link.T_local is None:
            continue
        if (link.target, link.source) == (a, b):
            return link.T_local
        if (link.target, link.source) == (b, a):
            return invert_transform(link.T_local)
    raise RegistrationFailed(f"No link between scans {a} and {b}.")


def loop_closures(
    links: Sequence[Link], poses: Sequence[Transform | None]
) -> dict[str, float]:
    """Disagreement of each verified link left out of the tree with the tree's poses.

    Returns ``{"i-j": metres}``: how far the link's transform moves the source's
    points (taken at 10 m from its origin) from where the tree's poses put them. A
    large value flags a wrong link in the tree or a wrong link left out.
    """
    out: dict[str, float] = {}
    for link in links:
        if link.in_tree or not link.verified or link.T_local is None:
            continue
        Pa, Pb = poses[link.target], poses[link.source]
        if Pa is None or Pb is None:
            continue
        delta = invert_transform(Pa) @ Pb @ invert_transform(link.T_local)
        angle = float(np.arccos(np.clip((np.trace(delta[:3, :3]) - 1) / 2, -1, 1)))
        out[f"{link.target}-{link.source}"] = float(
            np.linalg.norm(delta[:3, 3]) + 10.0 * angle
        )
    return out


def scan_statuses(
    links: Sequence[Link],
    paths: Sequence[tuple[int, ...] | None],
    loops: dict[str, float],
) -> tuple[str, ...]:
    """Each scan's state, in the words of :mod:`amrst.review.verdict`.

    ``failed``: no verified link reaches it. ``needs review``: a link of its path
    needs review and no loop confirms it (a cycle through it of verified links that
    closes within ``LOOP_CONFIRM_M``), or its path goes through a scan at either end
    of a registered link that :func:`loop_closures` finds more than
    ``LOOP_TOLERANCE_M`` from the tree's poses (two confident links disagree: one of
    them is wrong). Else ``registered``; the reference (its path is itself) is
    registered.
    """
    return tuple(
        FAILED
        if path is None
        else NEEDS_REVIEW
        if doubts is None or doubts
        else REGISTERED
        for path, doubts in zip(paths, scan_doubts(links, paths, loops), strict=True)
    )


def scan_doubts(
    links: Sequence[Link],
    paths: Sequence[tuple[int, ...] | None],
    loops: dict[str, float],
) -> tuple[frozenset[tuple[int, int]] | None, ...]:
    """Return the unsure links each scan's pose rests on, as (target, source).

    Empty for a registered scan; the links of its path that need review and that no
    loop confirms (:func:`scan_statuses`) for one that needs review for them alone;
    None for a failed scan and for one two registered links disagree about (no one
    link of its path to check).
    """
    by_pair = {frozenset((ln.target, ln.source)): ln for ln in links}
    doubtful = {pair for pair, ln in by_pair.items() if ln.status != REGISTERED}
    doubtful -= loop_confirmed(links, paths, loops)
    contradicted: set[int] = set()
    for link in links:
        key = f"{link.target}-{link.source}"
        if link.status == REGISTERED and loops.get(key, 0.0) > LOOP_TOLERANCE_M:
            contradicted |= {link.target, link.source}
    out: list[frozenset[tuple[int, int]] | None] = []
    for path in paths:
        if path is None or set(path[1:]) & contradicted:
            out.append(None)
            continue
        steps = {frozenset(step) for step in itertools.pairwise(path)} & doubtful
        out.append(frozenset((by_pair[s].target, by_pair[s].source) for s in steps))
    return tuple(out)


def loop_confirmed(
    links: Sequence[Link],
    paths: Sequence[tuple[int, ...] | None],
    loops: dict[str, float],
) -> set[frozenset[int]]:
    """Return the links (scan pairs) on a cycle closing within ``LOOP_CONFIRM_M``.

    A verified link left out of the tree closes the cycle of the tree's paths to its
    two scans; :func:`loop_closures` measured how well.
    """
    out: set[frozenset[int]] = set()
    for link in links:
        a, b = link.target, link.source
        closes = loops.get(f"{a}-{b}", np.inf) <= LOOP_CONFIRM_M
        pa, pb = paths[a], paths[b]
        if link.in_tree or not closes or pa is None or pb is None:
            continue
        steps_a = {frozenset(s) for s in itertools.pairwise(pa)}
        steps_b = {frozenset(s) for s in itertools.pairwise(pb)}
        out |= (steps_a ^ steps_b) | {frozenset((a, b))}
    return out
