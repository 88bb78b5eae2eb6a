"""A tree's stored result, read back from ``results/<id>/`` without registering again.

The app shows a campaign tree from these files alone: every scan with its pose on the
reference and the path it took, every link with its state and score, the tree's
state and measures. :meth:`StoredTree.link_result` gives one link as the app's pair
workflow needs it (the world transform between its two scans, metrics, verdict), so
review, manual recovery, Fine and Export start from the stored result.

Read from ``scans.json`` (written by every run) and, for a two-scan tree, the pair's
``metrics.json`` (candidate score, verdict, coarse and fine metrics). Files of older
versions, which said ``verdict`` (verified, unverified, partial, failed) where these
say ``status`` (registered, needs review, failed), read as the same states. No Qt.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import numpy as np

from amrst.campaign.folder import has_result, of_other_scans, read_doc
from amrst.review.verdict import (
    FAILED,
    NEEDS_REVIEW,
    REGISTERED,
    STATUSES,
    scans_status,
)
from amrst.types import invert_transform

if TYPE_CHECKING:
    from pathlib import Path

    from amrst.campaign.manifest import Campaign
    from amrst.types import Transform

#: The words of older scans.json files as states (amrst.review.verdict.STATUSES): a
#: pair's candidate that did not verify is what the pair verdict calls failed; a
#: verified one is registered with a clear lead, else needs review.
OLD_STATUS = {"unverified": FAILED, "partial": NEEDS_REVIEW, "failed": FAILED}


def summary_status(doc: dict[str, Any], folder: Path) -> str:
    """Return the state of the tree whose scans.json is ``doc`` (any version's words).

    A two-scan tree of an older version takes its pair's verdict from ``metrics.json``
    in ``folder``, as the app shows it.
    """
    status = doc.get("status")
    if status in STATUSES:
        return str(status)
    if doc.get("n_scans") == 2:
        pair = (_pair_metrics(folder) or {}).get("verdict") or {}
        if pair.get("status") in STATUSES:
            return str(pair["status"])
    old = str(doc.get("verdict", ""))
    if old == "verified":
        return scans_status((True, True), float(doc.get("confidence", 0.0)))
    return OLD_STATUS.get(old, NEEDS_REVIEW)


def _pair_metrics(folder: Path) -> dict[str, Any] | None:
    """Return a pair tree's metrics.json in the current layout (None: none)."""
    from amrst.results.documents import upgrade_result

    doc = read_doc(folder / "metrics.json")
    try:
        return None if doc is None else upgrade_result(doc, "metrics")
    except (TypeError, ValueError, OverflowError):  # a version that is no number
        return doc


def _link_status(d: dict[str, Any]) -> tuple[str, bool]:
    """Return a stored link's state and whether its candidate verified (any version)."""
    if d.get("status") in STATUSES:
        return str(d["status"]), bool(d.get("verified"))
    verified = d.get("verdict") == "verified"
    confidence = float(d.get("confidence", 0.0))
    return scans_status((True, verified), confidence), verified


@dataclass(frozen=True)
class StoredScan:
    """One scan of a stored tree."""

    index: int
    spec: str  # as in the manifest, relative to the campaign folder
    file: Path  # absolute
    reached: bool
    path: tuple[int, ...] | None  # scans from the reference to this one
    T_reference_scan: Transform | None  # world: this scan -> the reference


@dataclass(frozen=True)
class StoredLink:
    """One link (pair of scans) of a stored tree, as the batch registered it."""

    target: int
    source: int
    status: str  # registered, needs review, failed
    verified: bool  # its candidate verified
    score: float
    confidence: float
    in_tree: bool
    origin: str
    message: str
    metrics: dict[str, Any] | None

    @property
    def key(self) -> tuple[int, int]:
        """``(target, source)`` scan numbers."""
        return (self.target, self.source)


@dataclass(frozen=True)
class StoredLinkResult:
    """One link's stored result in the form the app's pair workflow takes.

    ``T_world`` maps the source scan's world coordinates into the target's.
    """

    target: int
    source: int
    T_world: Transform
    verdict: dict[str, str]  # status, reason, next_step
    score: float
    confidence: float
    verified: bool
    origin: str
    metrics_fine: dict[str, Any] | None
    metrics_coarse: dict[str, Any] | None
    tree: dict[str, dict[str, Any]]
    params: dict[str, Any] | None
    label: str
    T_truth: Transform | None = None  # world T_target_source from the tree's truth
    # metrics.json's ``quality`` and ``strength`` sections (pair trees only).
    quality: dict[str, Any] | None = None
    strength: dict[str, Any] | None = None


@dataclass(frozen=True)
class StoredTree:
    """Everything stored for one tree (from ``scans.json`` and its neighbours)."""

    tree_id: str
    reference: int
    scans: tuple[StoredScan, ...]
    links: tuple[StoredLink, ...]
    status: str  # registered, needs review, failed
    confidence: float
    tree: dict[str, dict[str, Any]]
    params: dict[str, Any] | None
    pair_metrics: dict[str, Any] | None = field(default=None, repr=False)
    truth: tuple[Transform, ...] | None = None  # true T_reference_scan per scan

    def default_link(self) -> tuple[int, int]:
        """Return the link to show first: the reference and the first other scan."""
        other = next(s.index for s in self.scans if s.index != self.reference)
        return (self.reference, other)

    def link(self, target: int, source: int) -> StoredLink | None:
        """Return the stored link between two scans (either direction), or None."""
        for link in self.links:
            if {link.target, link.source} == {target, source}:
                return link
        return None

    def link_transform(self, target: int, source: int) -> Transform | None:
        """Return the world ``T_target_source`` from the stored poses (None: a scan not reached)."""
        T_t = self.scans[target].T_reference_scan
        T_s = self.scans[source].T_reference_scan
        if T_t is None or T_s is None:
            return None
        T: Transform = invert_transform(T_t) @ T_s
        return T

    def link_result(self, target: int, source: int) -> StoredLinkResult | None:
        """Return one link as the app's pair workflow takes it (None: a scan not reached)."""
        T = self.link_transform(target, source)
        if T is None:
            return None
        link = self.link(target, source)
        pair = self.pair_metrics
        label = f"tree {self.tree_id}, scans {target}-{source}"
        truth = None
        if self.truth is not None:
            truth = invert_transform(self.truth[target]) @ self.truth[source]
        if pair is not None and {target, source} == {0, 1} and target == self.reference:
            coarse = pair.get("coarse") or {}
            return StoredLinkResult(
                target=target,
                source=source,
                T_world=T,
                verdict=dict(pair.get("verdict") or _verdict_of(link, label)),
                score=float(coarse.get("verification_score", np.nan)),
                confidence=float(coarse.get("confidence", np.nan)),
                verified=bool(coarse.get("verified", False)),
                origin=str(coarse.get("candidate_origin", "tetrahedra")),
                metrics_fine=pair.get("fine"),
                metrics_coarse=coarse or None,
                tree=dict(pair.get("tree") or self.tree),
                params=self.params,
                label=label,
                T_truth=truth,
                quality=pair.get("quality"),
                strength=pair.get("strength"),
            )
        return StoredLinkResult(
            target=target,
            source=source,
            T_world=T,
            verdict=_verdict_of(link, label),
            score=np.nan if link is None else link.score,
            confidence=np.nan if link is None else link.confidence,
            verified=link is not None and link.verified,
            origin="tetrahedra" if link is None else (link.origin or "tetrahedra"),
            metrics_fine=None if link is None else link.metrics,
            metrics_coarse=None,
            tree=dict(self.tree),
            params=self.params,
            label=label,
            T_truth=truth,
        )


def _verdict_of(link: StoredLink | None, label: str) -> dict[str, str]:
    if link is None:
        return {
            "status": NEEDS_REVIEW,
            "reason": f"No link of its own was registered for {label}; the pose comes "
            "from the poses of both scans on the reference.",
            "next_step": "Check the overlay; run Fine to refine this pair.",
        }
    status = link.status
    how = "in the spanning tree" if link.in_tree else "not used by the spanning tree"
    return {
        "status": status,
        "reason": f"Link {link.target}-{link.source}: {status} by the batch "
        f"(score {link.score:.0%}, confidence {link.confidence:.0%}, {how}); the pose "
        f"shown comes from both scans' final poses. {link.message}".strip(),
        "next_step": "Accept the tree in the Campaign dock."
        if status == REGISTERED
        else "Review the overlay; recover the pose by hand or run Fine if it is wrong.",
    }


def _matrix(value: Any) -> Transform | None:
    if value is None:
        return None
    T = np.asarray(value, dtype=float)
    return T if T.shape == (4, 4) else None


def read_stored_tree(campaign: Campaign, tree_id: str) -> StoredTree | None:
    """Read a tree's stored result; None when it has none (not run, or failed).

    The scans are the manifest's (the same order as the result's ``scans``).
    """
    entry = campaign.tree(tree_id)
    out = campaign.results_dir(tree_id)
    if not has_result(out) or of_other_scans(out, entry):  # no poses of these scans
        return None
    doc = read_doc(out / "scans.json")
    if doc is None or len(doc.get("scans", [])) != len(entry.scans):
        return None
    scans = tuple(
        StoredScan(
            index=k,
            spec=spec,
            file=campaign.root / spec,
            reached=bool(s.get("reached")),
            path=None if s.get("path") is None else tuple(s["path"]),
            T_reference_scan=_matrix(s.get("T_reference_scan")),
        )
        for k, (spec, s) in enumerate(zip(entry.scans, doc["scans"], strict=True))
    )
    links = tuple(
        StoredLink(
            int(d["target"]),
            int(d["source"]),
            *_link_status(d),
            score=float(d.get("score", np.nan)),
            confidence=float(d.get("confidence", np.nan)),
            in_tree=bool(d.get("in_tree")),
            origin=str(d.get("origin", "")),
            message=str(d.get("message", "")),
            metrics=d.get("metrics"),
        )
        for d in doc.get("links", [])
    )
    pair = _pair_metrics(out) if len(scans) == 2 else None
    truth = None
    if entry.truth is not None:
        from amrst.errors import AmrstError
        from amrst.multiscan.export import read_scan_truth

        try:
            reference = int(doc.get("reference", entry.reference))
            truth = tuple(
                read_scan_truth(campaign.root / entry.truth, len(scans), reference)
            )
        except AmrstError:  # a bad truth file: the result shows without truth errors
            truth = None
    return StoredTree(
        tree_id=tree_id,
        reference=int(doc.get("reference", entry.reference)),
        scans=scans,
        links=links,
        status=summary_status(doc, out),
        confidence=float(doc.get("confidence", np.nan)),
        tree=dict(doc.get("tree") or {}),
        params=read_doc(out / "params.json"),
        pair_metrics=pair,
        truth=truth,
    )
