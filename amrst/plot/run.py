"""One run of a plot, as ``amrst plot`` and the app's Plot window both make it.

:func:`run_plot` checks the output folder and the inputs before any scan is
registered, reads the scans, registers them (``amrst.plot.register``), takes the
inventory with the trees the technician added (``amrst.plot.inventory``) and writes
the folder (``amrst.plot.export``).
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from amrst.errors import InvalidInput
from amrst.progress import NULL_REPORTER, Reporter, SubReporter

if TYPE_CHECKING:
    from collections.abc import Collection, Mapping, Sequence

    from amrst.plot.inventory import Inventory
    from amrst.plot.register import PlotRegistration, PlotScan
    from amrst.plot.stand import PlotArea
    from amrst.types import Cloud

#: A plot centre this near the reference scan's points is in its coordinates: a
#: circle holding none of them is too small, not misplaced (m).
NEAR_CENTRE_M = 30.0


@dataclass(frozen=True, slots=True)
class PlotRun:
    """What a run registered, listed and wrote."""

    labels: tuple[str, ...]  # one per scan, as the files name them
    registration: PlotRegistration
    inventory: Inventory
    written: tuple[Path, ...]
    states: tuple[str, ...]  # each scan's state (registered, accepted, ...)
    lost: tuple[str, ...]  # the review that found no tree at this run
    area: PlotArea | None = None  # the fixed-radius plot asked for
    notes: tuple[str, ...] = ()  # --accept: links it left alone, and why


def run_plot(
    specs: Sequence[str],
    out: Path,
    *,
    overwrite: bool = False,
    pairs: Mapping[tuple[int, int], str] | None = None,
    left_out: Collection[tuple[int, int]] = (),
    accept: Collection[tuple[int, int]] = (),
    scanners: Mapping[int, tuple[float, float, float]] | None = None,
    write_trees: bool = False,
    write_cloud: bool = False,
    report: bool = False,
    plot_radius_m: float | None = None,
    plot_centre: tuple[float, float] | None = None,
    reporter: Reporter = NULL_REPORTER,
) -> PlotRun:
    """Register and inventory the plot whose scans ``specs`` name; write it to ``out``.

    Parameters
    ----------
    specs : sequence of str
        Scan files (``FILE.e57`` gives all its scans, ``FILE.e57#k`` one); the first
        scan is the reference.
    out : Path
        The results folder (:func:`amrst.plot.export.check_out`).
    overwrite : bool
        Replace a plot another run wrote there.
    pairs : mapping of (int, int) to str, or None
        Links placed from point pairs: ``{(i, j): pairs CSV}``, scans from 0.
    left_out : collection of (int, int)
        Links not to register (found wrong).
    accept : collection of (int, int)
        Links that needed review at the folder's last run, which the technician
        checked and accepts at the pose that run gave them, as the app's Accept: kept
        in ``review.json`` (:func:`checked_poses`). A link that needs no review now, or
        whose pose moved since, gets a note in ``PlotRun.notes``.
    scanners : mapping of int to (float, float, float), or None
        Where a scan's scanner stood, ``{scan from 0: (x, y, z)}`` in its file's
        coordinates: for a scan whose file does not say (a georeferenced LAS), so
        that its tops are checked. A scan whose file says is refused.
    write_trees, write_cloud, report : bool
        Also one cloud per tree, ``plot.laz``, ``report.html``.
    plot_radius_m, plot_centre : float or None, (float, float) or None
        A fixed-radius plot: the stand figures count the trees inside, per hectare.
        The centre is in the reference scan's file coordinates, as ``trees.csv``
        gives positions; without one, where the reference's scanner stood (an E57 or
        PTX file says; any other file: its origin, the scanner of a scan in its
        scanner's frame).
    reporter : Reporter

    Raises
    ------
    InvalidInput
        A folder or an input that cannot make a plot; raised before the scans are
        registered.
    """
    from amrst.files.outdir import clear_dead_run, folder_stamp
    from amrst.io.scans import one_scan_specs
    from amrst.plot.export import MANAGED, check_out, write_plot
    from amrst.plot.inventory import take_inventory
    from amrst.plot.register import check_links, register_plot
    from amrst.plot.review import read_review
    from amrst.review.pairs_file import read_pairs

    clear_dead_run(out)  # a killed run's set finished first, so the stamp holds
    check_out(out, overwrite)
    before = folder_stamp(out, MANAGED)  # what this run may replace, not another's
    _check_inputs([*specs, *(pairs or {}).values()], out)
    by_hand = {link: read_pairs(Path(f)) for link, f in (pairs or {}).items()}
    area = _plot_area(plot_radius_m, plot_centre)
    labels = [spec for spec, _name in one_scan_specs(specs)]
    _check_count(labels, scanners or {})
    _, _, accepting = check_links(len(labels), 0, by_hand, left_out, accept)
    checked = checked_poses(out, labels, accepting)
    added = read_review(out, labels).added  # before minutes of work, as check_out
    scans, area = _read_scans(
        labels, scanners or {}, area, plot_centre, SubReporter(reporter, 0.0, 0.4)
    )
    reg = register_plot(
        scans,
        0,
        reporter=SubReporter(reporter, 0.4, 0.8),
        by_hand=by_hand,
        left_out=left_out,
    )
    accepted, notes = reg.to_accept(checked)
    inventory = take_inventory(
        [s.analysis.cloud for s in scans],
        reg.poses,
        0,
        reporter=SubReporter(reporter, 0.8, 0.95, "inventory"),
        given=added,
    )
    reporter.progress(0.95, "Writing the plot")
    written, states, lost = write_plot(
        out,
        reg,
        inventory,
        labels,
        write_trees=write_trees,
        write_cloud=write_cloud,
        report=report,
        pairs_files={link: str(Path(f).resolve()) for link, f in (pairs or {}).items()},
        area=area,
        accepted=accepted,
        unchanged=before,
    )
    reporter.progress(1.0, "Plot written")
    return PlotRun(
        tuple(labels),
        reg,
        inventory,
        tuple(written),
        tuple(states),
        tuple(lost),
        area,
        tuple(notes),
    )


def checked_poses(
    out: Path, labels: Sequence[str], links: Collection[tuple[int, int]]
) -> dict[tuple[int, int], np.ndarray]:
    """Return the poses ``out``'s last run gave ``links`` (in their own order).

    What the technician checked is that run's pose (its report, the app's overlay),
    not the one the next run will compute.

    Raises
    ------
    InvalidInput
        No earlier run of these scans in ``out``, or a link it did not place.
    """
    from amrst.plot.export import read_plot_json
    from amrst.plot.review import same_scans
    from amrst.types import check_rigid

    if not links:
        return {}
    try:
        doc = read_plot_json(out)
    except (OSError, ValueError):
        doc = {}
    scans = [s for s in doc.get("scans", []) if isinstance(s, dict)]
    given = [str(s.get("label")) for s in scans]
    # By content where the paths differ: the same scans moved or copied since.
    if not same_scans(given, labels, [s.get("file_id") for s in scans]):
        raise InvalidInput(
            f"--accept takes the pose of a link you checked in {out}'s last run of "
            "these scans, and there is none: run the plot first, check the link "
            "(--report, the app's Plot window), then run it again with --accept."
        )
    poses = {}
    for i, j in sorted(links):
        entry = next(
            (
                ln
                for ln in doc.get("links", [])
                if isinstance(ln, dict)
                and (ln.get("target"), ln.get("source")) == (i, j)
            ),
            {},
        )
        T = entry.get("T_target_source")
        if T is None:
            raise InvalidInput(
                f"The link of scans {i + 1} and {j + 1} has no pose in {out}'s last "
                "run: there is nothing to accept."
            )
        poses[i, j] = check_rigid(T, f"the link {i + 1}-{j + 1} in plot.json")
    return poses


def _check_inputs(specs: Sequence[str], out: Path) -> None:
    """Refuse an input (scan, pairs file) the run would replace in ``out`` or below."""
    from amrst.plot.export import MANAGED, TREES_DIR
    from amrst.results.export import refuse_inputs_in_out

    refuse_inputs_in_out(out, specs, lambda name: name in MANAGED)
    refuse_inputs_in_out(out / TREES_DIR, specs, lambda _name: True)


#: A scanner given by hand stands within this of its scan's points (m, horizontally) ...
SCANNER_NEAR_M = 5.0
#: ... and up to this above the lowest of them (m): a tripod on rough ground.
SCANNER_UP_M = 4.0


def _check_count(
    labels: Sequence[str], scanners: Mapping[int, tuple[float, float, float]]
) -> None:
    """Refuse what no run can use: fewer than two scans, or one given twice.

    ``p.e57`` and ``p.e57#3`` name scan 3 twice. A scanner given for a scan that is
    not there is refused too.
    """
    if len(labels) < 2:
        raise InvalidInput(
            f"{len(labels)} scan given: a plot needs at least two positions."
        )
    seen: set[str] = set()
    for label in labels:
        head, sep, tail = label.rpartition("#")
        key = f"{Path(head).resolve()}#{tail}" if sep else str(Path(label).resolve())
        if key in seen:
            whole = " (a file of several scans gives them all)" if sep else ""
            raise InvalidInput(
                f"{label} is given twice{whole}: give each position's scan once."
            )
        seen.add(key)
    for k, xyz in sorted(scanners.items()):
        if not 0 <= k < len(labels):
            raise InvalidInput(
                f"{_scanner_text(k, xyz)}: there are {len(labels)} scans; name one of "
                "them by its number from 1."
            )


def _scanner_text(k: int, xyz: tuple[float, float, float]) -> str:
    return f"The scanner of scan {k + 1} at {', '.join(f'{v:.2f}' for v in xyz)}"


def _read_scans(
    labels: Sequence[str],
    scanners: Mapping[int, tuple[float, float, float]],
    area: PlotArea | None,
    centre: tuple[float, float] | None,
    reporter: Reporter,
) -> tuple[list[PlotScan], PlotArea | None]:
    """Read and analyse the scans one at a time, keeping what the plot needs of each.

    Memory holds one scan as read, however many positions: each is analysed and
    thinned to its working points (``PlotScan``) before the next is read. Returns
    them and the plot circle, centred where the reference's scanner stood when no
    ``centre`` is given.

    Raises
    ------
    InvalidInput
        A scan :func:`amrst.io.checks.check_scans` refuses, a scanner given that
        :func:`_with_scanner` refuses, or a plot circle holding none of the
        reference's points.
    """
    from dataclasses import replace

    from amrst.io.checks import refuse_odd_coordinates, refuse_same_points
    from amrst.io.scans import file_stamp, read_scans
    from amrst.plot.register import analyse_plot_scan, plot_params
    from amrst.plot.stemmap import StemMapParams

    params, stem_params = plot_params(), StemMapParams()
    n = len(labels)
    scans: list[PlotScan] = []
    for k, label in enumerate(labels):
        reporter.progress(k / n, f"Reading scan {k + 1} of {n}")
        t0 = time.perf_counter()
        (cloud,) = read_scans(label)
        read_s = time.perf_counter() - t0
        refuse_odd_coordinates(cloud, label)
        if k in scanners:
            cloud = _with_scanner(cloud, k, label, scanners[k])
        if k == 0 and area is not None:
            area = area if centre is not None else _at_scanner(area, cloud)
            _check_centre(area, cloud, label, given=centre is not None)
        sub = SubReporter(reporter, (k + 0.2) / n, (k + 1) / n, f"scan {k + 1}")
        scan = analyse_plot_scan(cloud, params, stem_params, sub)
        scans.append(replace(scan, file_stamp=file_stamp(label), read_seconds=read_s))
        del cloud  # before the next scan is read
        refuse_same_points(  # the working points, thinned on the stem map's voxels
            [s.analysis.cloud for s in scans], labels[: k + 1], stem_params.voxel_m
        )
    return scans, area


def _with_scanner(
    cloud: Cloud, k: int, label: str, xyz: tuple[float, float, float]
) -> Cloud:
    """Return scan ``k`` with the scanner position given (``scanner_origin``).

    Raises
    ------
    InvalidInput
        A scan whose file says where its scanner stood (and near its points), or a
        position with no ground of its scan just below it (not in the scan file's
        coordinates, or mistyped).
    """
    from dataclasses import replace

    from amrst.plot.inventory import scanner_at
    from amrst.sampling import strided

    what = _scanner_text(k, xyz)
    if scanner_at(cloud) is not None and "scanner_origin" in cloud.meta:
        raise InvalidInput(
            f"{what}: {label} says where its scanner stood; give a position only for "
            "a scan whose file does not."
        )
    at = np.asarray(xyz, float) - cloud.offset
    pts = strided(cloud.xyz, 200_000)
    near = pts[np.hypot(*(pts[:, :2] - at[:2]).T) <= SCANNER_NEAR_M]
    ground = float(np.percentile(near[:, 2], 2)) if len(near) >= 10 else np.nan
    if not (ground - 1.0 <= at[2] <= ground + SCANNER_UP_M):
        raise InvalidInput(
            f"{what}: {label} has no ground just below that point (within "
            f"{SCANNER_NEAR_M:g} m across and {SCANNER_UP_M:g} m down): give where "
            "its scanner stood, in the scan file's coordinates."
        )
    meta = {**cloud.meta, "scanner_origin": tuple(xyz), "scanner_given": True}
    return replace(cloud, meta=meta)


def _plot_area(
    radius_m: float | None, centre: tuple[float, float] | None
) -> PlotArea | None:
    """Check the fixed-radius plot asked for before any scan is read.

    Without a centre it stands at the origin until :func:`_at_scanner` moves it.
    """
    from amrst.plot.stand import PlotArea

    if radius_m is None:
        if centre is not None:
            raise InvalidInput(
                "A plot centre needs the plot's radius too (--plot-radius R)."
            )
        return None
    x, y = (0.0, 0.0) if centre is None else centre
    return PlotArea((float(x), float(y)), float(radius_m))


def _at_scanner(area: PlotArea, reference: Cloud) -> PlotArea:
    """Return the plot centred where the reference's scanner stood, when known."""
    from amrst.plot.inventory import scanner_at
    from amrst.plot.stand import PlotArea

    at = scanner_at(reference)
    if at is None:
        return area
    x, y = (at + reference.offset)[:2]
    return PlotArea((float(x), float(y)), area.radius_m)


def _check_centre(area: PlotArea, reference: Cloud, label: str, *, given: bool) -> None:
    """Refuse a plot circle that holds none of the reference scan's points."""
    step = max(1, len(reference.xyz) // 200_000)  # a coarse check needs few points
    xy = reference.xyz[::step, :2] - (np.asarray(area.centre_xy) - reference.offset[:2])
    nearest = float(np.hypot(xy[:, 0], xy[:, 1]).min()) if len(xy) else math.inf
    if nearest <= area.radius_m:
        return
    cx, cy = area.centre_xy
    where = (
        f"its nearest point is {nearest:.1f} m from the centre: give a larger radius"
        if nearest <= NEAR_CENTRE_M
        else f"give the centre in {label}'s coordinates, as trees.csv gives positions"
        if given
        else f"{label}'s coordinates are far from their origin (georeferenced?): give "
        "the plot centre in them (amrst plot --plot-centre X Y, or the Plot "
        "window's centre field)"
    )
    raise InvalidInput(
        f"The plot circle of {area.radius_m:g} m around ({cx:g}, {cy:g}) holds none "
        f"of {label}'s points: {where}."
    )
