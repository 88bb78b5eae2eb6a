"""What the Plot window runs in the engine process, and its review file. No Qt.

:func:`run_plot` is ``amrst plot SCANS --out DIR`` for the app: it reads the scans,
registers them (``amrst.plot.register``), takes the inventory
(``amrst.plot.inventory``) and writes the plot into the results folder
(``amrst.plot.export``), then hands back a :class:`PlotOutcome`: what the stem map
and the tree view draw, a few thousand points at most, never the scans.

:func:`reviewed` shows the outcome with the technician's review
(``amrst.plot.review``): the links they accepted, and the scans those place.
"""

from __future__ import annotations

import json
import time
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import numpy as np

from amrst.errors import InvalidInput
from amrst.plot.diameter import BREAST_HEIGHT_M
from amrst.progress import Reporter, SubReporter
from amrst.review.verdict import FAILED, NEEDS_REVIEW, REGISTERED

if TYPE_CHECKING:
    from collections.abc import Collection, Mapping, Sequence
    from pathlib import Path

    from amrst.campaign.stored import StoredLinkResult
    from amrst.plot.inventory import Inventory, Tree
    from amrst.plot.register import PlotRegistration
    from amrst.types import Cloud

#: The slices shown per tree: their middles above the local ground (breast height
#: the DBH's, the others to see the stem below and above it), half their thickness.
SLICE_HEIGHTS_M = (0.6, BREAST_HEIGHT_M, 2.0, 3.0)
SLICE_HALF_M = 0.05
#: The slices follow the stem line: through the DBH centre, leaning as the stem map
#: measured, towards the DBH centre from the foot; at most ``MAX_LEAN_PER_M``.
MAX_LEAN_PER_M = 0.2
#: Points kept around the stem in the slice (m beyond its radius).
SLICE_MARGIN_M = 0.3
#: Cell of the top view drawn under the stem map (m).
TOP_CELL_M = 0.25
#: Vegetation in the top view: points this high above the ground.
TOP_MIN_HEIGHT_M = 0.5


@dataclass(frozen=True, slots=True)
class ScanPlace:
    """One scan of the plot: its label, where it stood (reference frame), its stems
    and its state (registered / needs review / failed)."""

    label: str
    xy: np.ndarray | None  # (2,) the scanner's position; None: not placed
    stems: int
    status: str
    # The unsure links its pose rests on (None: none a person can clear).
    doubts: frozenset[tuple[int, int]] | None = frozenset()


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
    rmse_m: float
    shared: int
    message: str
    score: float = float("nan")  # the point score of its pose
    # Its pose: the source scan's file coordinates into the target's (None: failed),
    # as plot.json and review.json give it; a point among the source's (its offset).
    T_world: np.ndarray | None = None
    at: np.ndarray = field(default_factory=lambda: np.zeros(3))

    @property
    def key(self) -> tuple[int, int]:
        return self.target, self.source


@dataclass(frozen=True, slots=True)
class TreeSlice:
    """The points around one stem at one height and the scan each came from."""

    xy: np.ndarray  # (N, 2) reference local frame
    scan: np.ndarray  # (N,) 0-based scan index
    height_m: float = BREAST_HEIGHT_M  # above the local ground
    centre: np.ndarray | None = None  # (2,) the stem line there; None: the DBH's


@dataclass(frozen=True, slots=True)
class TopView:
    """Vegetation density seen from above: ``image[row, col]``, row 0 at ``y0``."""

    image: np.ndarray  # (H, W) uint8
    x0: float
    y0: float
    cell_m: float


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

    @property
    def tree_xy(self) -> np.ndarray:
        """(S, 2) the breast-height centre of every tree (reference local frame)."""
        return np.array([t.stem.dbh_xy for t in self.trees], float).reshape(-1, 2)

    @property
    def missing(self) -> list[str]:
        """Labels of the scans no verified link placed."""
        return self.labelled(FAILED)

    def labelled(self, status: str) -> list[str]:
        """Labels of the scans in ``status``."""
        return [s.label for s in self.scans if s.status == status]


def run_plot(
    specs: Sequence[str],
    out: Path,
    overwrite: bool,
    reporter: Reporter,
    *,
    pairs: Mapping[tuple[int, int], str] | None = None,
    left_out: Collection[tuple[int, int]] = (),
    write_cloud: bool = False,
) -> PlotOutcome:
    """Register and inventory the plot ``specs`` names; write it into ``out``.

    ``pairs``: links to place from point pairs, ``{(i, j): pairs CSV}`` (as ``amrst
    plot --pairs``, scans from 0); ``left_out``: links not to register (``amrst plot
    --leave-out``); ``write_cloud``: also the registered plot (``--write-cloud``).
    """
    from pathlib import Path

    from amrst.multiscan.cli import read_specs
    from amrst.plot.export import check_out, write_plot
    from amrst.plot.inventory import take_inventory
    from amrst.plot.register import register_plot
    from amrst.review.pairs_file import read_pairs

    start = time.perf_counter()
    check_out(out, overwrite)
    by_hand = {link: read_pairs(Path(f)) for link, f in (pairs or {}).items()}
    reporter.progress(0.0, "Reading the scans")
    clouds, labels = read_specs(list(specs))
    if len(clouds) < 2:
        raise InvalidInput(
            f"{len(clouds)} scan given: a plot needs at least two positions; "
            "open two or more scans."
        )
    reporter.check_cancelled()
    reg = register_plot(
        clouds,
        0,
        reporter=SubReporter(reporter, 0.05, 0.8),
        by_hand=by_hand,
        left_out=left_out,
    )
    inventory = take_inventory(
        clouds, reg.poses, 0, reporter=SubReporter(reporter, 0.8, 0.95, "inventory")
    )
    reporter.progress(0.95, "Writing the plot")
    write_plot(out, reg, inventory, labels, clouds, write_cloud=write_cloud)
    reporter.progress(1.0, "Plot written")
    return PlotOutcome(
        out=out,
        labels=tuple(labels),
        trees=inventory.trees,
        scans=_scan_places(reg, labels),
        links=tuple(
            _link_line(pl, reg.loop_confirms(pl.link), clouds) for pl in reg.links
        ),
        bundle_rmse_m=reg.bundle_rmse_m,
        slices=tuple(tree_slices(inventory, k) for k in range(len(inventory.trees))),
        top=top_view(inventory),
        seconds=time.perf_counter() - start,
    )


def _scan_places(reg: PlotRegistration, labels: Sequence[str]) -> tuple[ScanPlace, ...]:
    return tuple(
        ScanPlace(
            label,
            None if pose is None else np.asarray(pose[:2, 3], float),
            len(scan.stems.stems),
            status,
            doubts,
        )
        for label, pose, scan, status, doubts in zip(
            labels, reg.poses, reg.scans, reg.statuses, reg.doubts(), strict=True
        )
    )


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


def _link_line(pl: Any, confirmed: bool, clouds: Sequence[Cloud]) -> LinkLine:
    """The link as drawn: registered when a loop of links confirms it."""
    from amrst.types import world_transform

    link, m = pl.link, pl.link.metrics
    T_world = None
    if link.T_local is not None:
        T_world = world_transform(
            link.T_local, clouds[link.target], clouds[link.source]
        )
    return LinkLine(
        target=link.target,
        source=link.source,
        status=REGISTERED if confirmed else link.status,
        confirmed=confirmed and link.status != REGISTERED,
        in_tree=link.in_tree,
        origin=link.origin,
        overlap=float("nan") if m is None else float(m.overlap_fraction),
        rmse_m=float("nan") if m is None else float(m.rmse_overlap_m),
        shared=len(pl.shared),
        message=link.message,
        score=float(link.score),
        T_world=T_world,
        at=np.asarray(clouds[link.source].offset, float),
    )


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
        confidence=float("nan"),
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


def tree_slices(inventory: Inventory, k: int) -> tuple[TreeSlice, ...]:
    """The merged plot's points around tree k at each of ``SLICE_HEIGHTS_M`` (± 5 cm
    above the local ground), around its stem line (``MAX_LEAN_PER_M``)."""
    sm = inventory.stem_map
    stem = inventory.trees[k].stem
    dbh_xy = np.asarray(stem.dbh_xy, float)
    towards = dbh_xy - np.asarray(stem.base[:2], float)
    norm = float(np.hypot(*towards))
    per_m = min(np.tan(np.radians(np.nan_to_num(stem.lean_deg))), MAX_LEAN_PER_M)
    lean = towards / norm * per_m if norm > 1e-3 else np.zeros(2)
    radius = (stem.dbh_m / 2 if np.isfinite(stem.dbh_m) else 0.2) + SLICE_MARGIN_M
    reach = radius + MAX_LEAN_PER_M * max(
        abs(z - BREAST_HEIGHT_M) for z in SLICE_HEIGHTS_M
    )
    near = np.flatnonzero(np.hypot(*(sm.xyz[:, :2] - dbh_xy).T) <= reach)
    h = sm.ground.height(sm.xyz[near]) if len(near) else np.zeros(0)
    out = []
    for z in SLICE_HEIGHTS_M:
        centre = dbh_xy + lean * (z - BREAST_HEIGHT_M)
        keep = near[
            (np.abs(h - z) <= SLICE_HALF_M)
            & (np.hypot(*(sm.xyz[near, :2] - centre).T) <= radius)
        ]
        out.append(
            TreeSlice(
                np.asarray(sm.xyz[keep, :2], float),
                np.asarray(inventory.scan_of_point[keep], np.int64),
                z,
                centre,
            )
        )
    return tuple(out)


def top_view(inventory: Inventory) -> TopView | None:
    """The plot's vegetation seen from above (log density), None without ground."""
    sm = inventory.stem_map
    if not sm.ground.found or not len(sm.xyz):
        return None
    pts = sm.xyz[sm.ground.height(sm.xyz) >= TOP_MIN_HEIGHT_M]
    if not len(pts):
        return None
    lo = np.floor(pts[:, :2].min(axis=0) / TOP_CELL_M) * TOP_CELL_M
    cells = np.floor((pts[:, :2] - lo) / TOP_CELL_M).astype(np.int64)
    shape = cells.max(axis=0) + 1
    counts = np.zeros((shape[1], shape[0]), np.float64)
    np.add.at(counts, (cells[:, 1], cells[:, 0]), 1.0)
    scaled = np.log1p(counts) / max(float(np.log1p(counts.max())), 1e-9)
    image = np.round(255 * scaled).astype(np.uint8)
    return TopView(image, float(lo[0]), float(lo[1]), TOP_CELL_M)


def same_plot(out: Path, labels: Sequence[str]) -> bool:
    """Tell whether ``out`` holds a plot of exactly these scans (a run again)."""
    from amrst.plot.export import PLOT_JSON
    from amrst.plot.review import same_scans

    try:
        doc = json.loads((out / PLOT_JSON).read_text())
        return same_scans([s["label"] for s in doc["scans"]], labels)
    except (OSError, ValueError, KeyError, TypeError):
        return False
