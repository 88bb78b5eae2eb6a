"""What the Plot window runs in the engine process, and its review file. No Qt.

:func:`run_plot` is ``amrst plot SCANS --out DIR`` for the app: the same run
(``amrst.plot.run``) writes the plot into the results folder. :func:`open_results`
reads such a folder back, whoever wrote it, as a :class:`PlotOutcome`: what the stem
map and the tree view draw, a few thousand points at most, never the scans. A run
hands back its folder read that way, so the window shows what the files say.

:func:`reviewed` shows the outcome with the technician's review
(``amrst.plot.review``): the links they accepted, and the scans those place.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import numpy as np

from amrst.errors import InvalidInput
from amrst.plot.stand import PlotArea
from amrst.plot.view import scanner_position
from amrst.review.verdict import FAILED, NEEDS_REVIEW, REGISTERED

if TYPE_CHECKING:
    from collections.abc import Collection, Mapping, Sequence
    from pathlib import Path

    from amrst.campaign.stored import StoredLinkResult
    from amrst.plot.inventory import Tree
    from amrst.plot.view import TopView, TreeProfile, TreeSlice
    from amrst.progress import Reporter


@dataclass(frozen=True, slots=True)
class ScanPlace:
    """One scan of the plot: its label, where it stood (reference frame), its stems
    and its state (registered / needs review / failed)."""

    label: str
    xy: np.ndarray | None  # (2,) the scanner's position; None: not placed or not known
    stems: int
    status: str
    # The unsure links its pose rests on (None: none a person can clear).
    doubts: frozenset[tuple[int, int]] | None = frozenset()
    # Where its scanner stood as given by hand (plot.json scanner_given; its file's
    # coordinates).
    given: tuple[float, float, float] | None = None
    # Its distance to the other scans' surfaces (m; NaN: not placed or not known).
    residual_m: float = float("nan")
    # Its name in its file (an E57 setup's; "" when none).
    name: str = ""
    # How it seems to stand when it failed without a stem ("" else; plot.json turned).
    turned: str = ""

    @property
    def placed(self) -> bool:
        """Whether the registration placed the scan (only a failed one it did not)."""
        return self.status != FAILED


@dataclass(frozen=True, slots=True)
class LinkLine:
    """One link between two scans as the stem map draws it."""

    target: int
    source: int
    status: str  # registered / needs review / failed
    confirmed: bool  # registered by a loop of links, unsure on its own
    in_tree: bool
    origin: str
    overlap: float
    residual_m: float  # the source's distance to the target's surfaces (NaN: none)
    shared: int
    message: str
    score: float = float("nan")  # the point score of its pose
    # Its pose: the source scan's file coordinates into the target's (None: failed),
    # as plot.json and review.json give it; a point among the source's (its offset).
    T_world: np.ndarray | None = None
    at: np.ndarray = field(default_factory=lambda: np.zeros(3))
    # Placed from point pairs: ((scan of the target points, of the source's), file).
    pairs: tuple[tuple[int, int], str] | None = None
    confidence: float = float("nan")  # the confidence its status was judged by

    @property
    def key(self) -> tuple[int, int]:
        return self.target, self.source


@dataclass(frozen=True, slots=True)
class PlotOutcome:
    """A registered and inventoried plot, as the Plot window shows it.

    Positions are in the reference scan's local frame (``Tree.xyz`` holds the world
    ones, as trees.csv lists them).
    """

    out: Path
    labels: tuple[str, ...]
    trees: tuple[Tree, ...]
    scans: tuple[ScanPlace, ...]
    links: tuple[LinkLine, ...]
    bundle_rmse_m: float
    slices: tuple[tuple[TreeSlice, ...], ...]  # per tree, one per SLICE_HEIGHTS_M
    top: TopView | None
    seconds: float
    profiles: tuple[TreeProfile, ...] = ()  # per tree, its side view's points
    lost: tuple[str, ...] = ()  # the review this run found no tree for (dropped)
    area: PlotArea | None = None  # the fixed-radius plot, file coordinates
    reference_at: tuple[float, float] = (0.0, 0.0)  # the reference's local origin
    no_tree_why: str = ""  # why the plot lists no tree ("" when it lists one)

    @property
    def area_xy(self) -> np.ndarray | None:
        """(2,) the plot centre in the reference's local frame (None: no plot area)."""
        if self.area is None:
            return None
        return np.subtract(self.area.centre_xy, self.reference_at)

    @property
    def tree_xy(self) -> np.ndarray:
        """(S, 2) the breast-height centre of every tree (reference local frame)."""
        return np.array([t.stem.dbh_xy for t in self.trees], float).reshape(-1, 2)

    @property
    def missing(self) -> list[str]:
        """Labels of the scans no verified link placed."""
        return self.labelled(FAILED)

    @property
    def unsure(self) -> frozenset[int]:
        """The scans, numbered from 1, that need review (trees.csv scans_to_check)."""
        from amrst.plot.review import unsure_scans

        return unsure_scans([s.status for s in self.scans])

    def labelled(self, status: str) -> list[str]:
        """Labels of the scans in ``status``."""
        return [s.label for s in self.scans if s.status == status]


def scan_specs(paths: Sequence[str], reporter: Reporter) -> list[tuple[str, str]]:
    """Return one spec per scan the paths name, as a run numbers them, with its name.

    ``plot.e57`` of three scans gives ``plot.e57#0``, ``#1``, ``#2`` and the names of
    its setups (:func:`amrst.io.scans.one_scan_specs`). Reads headers (all of a PTX
    file's lines), no points; ``reporter`` is not used.
    """
    from amrst.io.scans import one_scan_specs

    return one_scan_specs(paths)


def run_plot(
    specs: Sequence[str],
    out: Path,
    overwrite: bool,
    reporter: Reporter,
    *,
    pairs: Mapping[tuple[int, int], str] | None = None,
    left_out: Collection[tuple[int, int]] = (),
    scanners: Mapping[int, tuple[float, float, float]] | None = None,
    write_cloud: bool = False,
    area: tuple[float, tuple[float, float] | None] | None = None,
) -> PlotOutcome:
    """Register and inventory the plot ``specs`` names; write it into ``out``.

    ``pairs``: links to place from point pairs, ``{(i, j): pairs CSV}`` (as ``amrst
    plot --pairs``, scans from 0); ``left_out``: links not to register (``amrst plot
    --leave-out``); ``scanners``: scanner positions given by hand, ``{scan from 0:
    (x, y, z)}`` in its file's coordinates (``--scanner``); ``write_cloud``: also the
    registered plot (``--write-cloud``);
    ``area``: the fixed-radius plot, (radius, centre or None: the origin), as
    ``--plot-radius`` and ``--plot-centre``.
    """
    from amrst.plot import run

    start = time.perf_counter()
    run.run_plot(
        specs,
        out,
        overwrite=overwrite,
        pairs=pairs,
        left_out=left_out,
        scanners=scanners,
        write_cloud=write_cloud,
        plot_radius_m=None if area is None else area[0],
        plot_centre=None if area is None else area[1],
        reporter=reporter,
    )
    return open_results(out, reporter, seconds=time.perf_counter() - start)


def open_results(
    out: Path, reporter: Reporter, *, seconds: float = float("nan")
) -> PlotOutcome:
    """Read the plot ``out`` holds (``amrst plot`` or a run of the app wrote it).

    Raises
    ------
    InvalidInput
        No plot there, or one whose files cannot be read (run it again).
    """
    from amrst.plot.export import read_plot

    reporter.progress(0.0, f"Reading the plot in {out}")
    files = read_plot(out)
    doc, view = files.doc, files.view
    try:
        labels = [_text(scan, "label") for scan in doc["scans"]]
        at = view.offsets[labels.index(doc["reference"])]
        scans = tuple(
            ScanPlace(
                label=scan["label"],
                xy=_scan_xy(scan, at),
                stems=int(scan["stems"]),
                status=_text(scan, "status"),
                doubts=None
                if scan["unsure_links"] is None
                else frozenset((int(t), int(s)) for t, s in scan["unsure_links"]),
                given=_given(scan.get("scanner_given")),
                residual_m=_float(scan.get("residual_m")),
                name=str(scan.get("name", "")),
                turned=str(scan.get("turned") or ""),
            )
            for scan in doc["scans"]
        )
        links = tuple(_link_line(entry, view.offsets) for entry in doc["links"])
        if any(not 0 <= k < len(scans) for ln in links for k in ln.key):
            raise ValueError("a link names a scan the plot does not have")
        bundle = _float(doc["bundle_rmse_m"])
        lost = tuple(str(v) for v in doc.get("review_lost") or ())
        no_tree_why = str(doc.get("no_tree_why") or "")
        area = PlotArea.from_dict(doc.get("plot_area"))
    except (
        KeyError,
        TypeError,
        ValueError,
        IndexError,
        AttributeError,
        InvalidInput,
    ) as exc:
        raise InvalidInput(
            f"{out} holds a plot.json this version cannot read ({exc}): run the "
            "plot again."
        ) from exc
    return PlotOutcome(
        out=out,
        labels=tuple(s.label for s in scans),
        trees=files.trees,
        scans=scans,
        links=links,
        bundle_rmse_m=bundle,
        slices=view.slices,
        top=view.top,
        seconds=seconds,
        profiles=view.profiles,
        lost=lost,
        area=area,
        reference_at=(float(at[0]), float(at[1])),
        no_tree_why=no_tree_why,
    )


def _link_line(entry: Mapping[str, Any], offsets: np.ndarray) -> LinkLine:
    """A plot.json link as drawn: registered when a loop of links confirms it.

    Raises ValueError or InvalidInput (an unreadable plot.json) for a text field that
    is not text or a pose that is not a rigid transform.
    """
    from amrst.types import check_rigid

    confirmed = bool(entry["loop_confirmed"])
    m = entry["metrics"] or {}
    T, p = entry["T_target_source"], entry["pairs"]
    source = int(entry["source"])
    status, origin, message = (
        _text(entry, key) for key in ("status", "origin", "message")
    )
    return LinkLine(
        target=int(entry["target"]),
        source=source,
        status=REGISTERED if confirmed else status,
        confirmed=confirmed and status != REGISTERED,
        in_tree=bool(entry["in_tree"]),
        origin=origin,
        overlap=_float(m.get("overlap_fraction")),
        residual_m=_float(entry.get("residual_m")),
        shared=int(entry["stems_shared"]),
        message=message,
        score=_float(entry["score"]),
        confidence=_float(entry.get("confidence")),
        T_world=None if T is None else check_rigid(T, "a link's T_target_source"),
        at=np.asarray(offsets[source], float),
        pairs=None if p is None else ((int(p["target"]), int(p["source"])), p["file"]),
    )


def _text(entry: Mapping[str, Any], key: str) -> str:
    """A plot.json text field; ValueError when it holds something else."""
    value = entry[key]
    if not isinstance(value, str):
        raise ValueError(f"{key} {str(value)[:40]!r} is not text")
    return value


def _given(value: Any) -> tuple[float, float, float] | None:
    """A scanner position given by hand, as plot.json records it (None: none).

    Raises ValueError (an unreadable plot.json) when it is no three finite numbers.
    """
    if value is None:
        return None
    x, y, z = (float(v) for v in value)
    if not all(math.isfinite(v) for v in (x, y, z)):
        raise ValueError(f"scanner_given {value} is not three finite numbers")
    return x, y, z


def _scan_xy(scan: Mapping[str, Any], reference: np.ndarray) -> np.ndarray | None:
    """Where a plot.json scan's scanner stood in the reference's local frame (None:
    not placed, or not known)."""
    at = scanner_position(scan)
    return None if at is None else np.asarray((at - reference)[:2], float)


def _float(value: Any) -> float:
    """A number of plot.json (null: NaN)."""
    return float("nan") if value is None else float(value)


def reviewed(
    found: PlotOutcome, accepted: Mapping[tuple[int, int], Any]
) -> PlotOutcome:
    """The outcome as the technician's review leaves it.

    A link that needs review and keeps the pose it was accepted at reads
    ``accepted``, and so does each scan that needs review for accepted links alone
    (``amrst.plot.review.scan_state``). An acceptance of another pose is named in the
    link's message; the link stays as the run found it.
    """
    from dataclasses import replace

    from amrst.plot.review import ACCEPTED, holding, pose_change, scan_state

    keep = holding(
        accepted, ((ln.key, ln.status, ln.T_world, ln.at) for ln in found.links)
    )
    links = []
    for ln in found.links:
        T = accepted.get(ln.key)
        if ln.key in keep:
            ln = replace(ln, status=ACCEPTED, message=f"Accepted by you. {ln.message}")
        elif T is not None and ln.status == NEEDS_REVIEW and ln.T_world is not None:
            turn, shift = pose_change(T, ln.T_world, ln.at)
            ln = replace(
                ln,
                message=f"You accepted a pose {turn:.2f} deg / {100 * shift:.1f} cm "
                f"from this one: check it again. {ln.message}",
            )
        links.append(ln)
    scans = tuple(
        replace(s, status=scan_state(s.status, s.doubts, keep)) for s in found.scans
    )
    return replace(found, links=tuple(links), scans=scans)


def stored_link(link: LinkLine) -> StoredLinkResult | None:
    """The link's pose as the main window shows a stored result (None: failed).

    The overlay and the verdict then show the plot link as it stands, with no step
    run; the Manual pose dock can pick pairs on it.
    """
    from amrst.campaign.stored import StoredLinkResult

    if link.T_world is None:
        return None
    name = f"plot link S{link.target + 1}–S{link.source + 1}"
    return StoredLinkResult(
        target=link.target,
        source=link.source,
        T_world=link.T_world,
        verdict={
            "status": link.status,
            "reason": f"The {name} is {link.status} (by {link.origin}). "
            f"{link.message}".strip(),
            "next_step": "Check the overlay, and each tree's slice in the plot "
            "window; when the pose is wrong, pick point pairs in the Manual pose dock, "
            "save them, and use them for this link in the plot window.",
        },
        score=link.score,
        confidence=link.confidence,
        verified=link.status != FAILED,
        origin=link.origin,
        metrics_fine=None,
        metrics_coarse=None,
        tree={},
        params=None,
        label=name,
    )


def report_job(out: Path, reporter: Reporter) -> Path:
    """Write report.html from the results folder's files (``plot.export``)."""
    from amrst.plot.export import write_report

    reporter.progress(0.0, "Writing the report")
    return write_report(out)


def run_of(out: Path, labels: Sequence[str]) -> bool:
    """Tell whether ``out``'s plot.json is a run of these very scan files (not of
    the same scans where they were before they moved: its labels name them).
    Reads a regular file only, as :func:`same_plot`."""
    from amrst.plot.export import read_plot_json
    from amrst.plot.review import same_scans

    try:
        theirs = [s["label"] for s in read_plot_json(out)["scans"]]
    except (OSError, ValueError, KeyError, TypeError):
        return False
    return same_scans(theirs, labels)


#: What ``out`` holds against the scans of a run (:func:`same_plot`).
SAME_SCANS = "same scans"
SAME_REFERENCE = "same reference"


def same_plot(out: Path, labels: Sequence[str]) -> str:
    """Tell whether ``out`` holds a plot of these scans: SAME_SCANS (a run again),
    SAME_REFERENCE (scans added or removed: the review of the trees holds), or "".

    Its plot.json tells; when that cannot be read, its review.json (the scans the
    technician's marks belong to, which a run keeps).
    """
    from amrst.plot.export import read_plot_json
    from amrst.plot.review import review_document, same_reference, same_scans

    # Both open regular files only: this runs on the GUI thread, which a named pipe
    # would block.
    try:
        doc = read_plot_json(out)
        theirs = [s["label"] for s in doc["scans"]]
        ids = [s.get("file_id") for s in doc["scans"]]
    except (OSError, ValueError, KeyError, TypeError, AttributeError):
        try:
            review = review_document(out)
            theirs, ids = list(review["scans"]), review.get("scan_ids")
        except (InvalidInput, KeyError, TypeError, AttributeError):
            return ""
    if same_scans(theirs, labels, ids):
        return SAME_SCANS
    return SAME_REFERENCE if same_reference(theirs, labels, ids) else ""
