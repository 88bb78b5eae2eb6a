"""What ``amrst plot`` hands over: the inventory, the links, the poses, the tree clouds.

Every file of a run is written into the output folder as one unit
(``files.outdir.replace_files``). A folder holding another run's ``plot.json`` is
refused unless the caller says to overwrite it. The inventory's last columns, ``mark``
and ``dbh_hand_m``, are the technician's (``amrst.plot.review``): a run writes what
the folder's review holds for these scans (``review.read_review``), and
:func:`write_inventory` writes the inventory again when the review changes. These
writes after the run (``write_inventory``, ``write_states``, ``write_area``) do not
wait for another writer of the folder: the app calls them on a click, and a folder
busy with another run is said at once (``FolderBusy``) rather than freezing it.
"""

from __future__ import annotations

import csv
import datetime as _dt
import io as _stdio
import os
import re
from dataclasses import dataclass, replace
from typing import TYPE_CHECKING, Any

import numpy as np

from amrst import __version__
from amrst.errors import InvalidInput
from amrst.files.outcheck import check_output_folder
from amrst.plot.flags import DBH_CHECK, DBH_OK, HEIGHT_FLAGS, OUTLIER_SHARE
from amrst.plot.inventory import TREE_COLUMNS, scanner_in_reference
from amrst.plot.report import REPORT
from amrst.plot.review import (
    PlotReview,
    followed,
    read_review,
    scan_id,
    unsure_scans,
    write_review,
)
from amrst.plot.view import VIEW_NPZ, PlotView, plot_view, read_view, view_writer

if TYPE_CHECKING:
    from collections.abc import Callable, Collection, Mapping, Sequence
    from pathlib import Path

    from amrst.files.outdir import FolderStamp
    from amrst.io.las_write import PointLabels
    from amrst.plot.inventory import Inventory, Tree
    from amrst.plot.register import PlotRegistration
    from amrst.plot.stand import PlotArea
    from amrst.types import Cloud, Transform

PLOT_JSON = "plot.json"
TREES_CSV = "trees.csv"
TREES_XLSX = "trees.xlsx"
TREES_DIR = "trees"
PLOT_CLOUD = "plot.laz"
#: trees.csv's columns: the tree's figures, the scans among ``seen_from`` whose pose
#: still needs review, the technician's mark and DBH, and whether the tree stands
#: inside the fixed-radius plot (empty without one).
INVENTORY_COLUMNS = (
    *TREE_COLUMNS,
    "scans_to_check",
    "mark",
    "dbh_hand_m",
    "in_plot",
)
#: What each column holds, for the reader of trees.xlsx (its "columns" sheet).
COLUMN_NOTES = {
    "tree_id": "T001... trees found, by position; H001... trees you added; stable "
    "between runs on the same files",
    "x_m": "stem base, m: the first (reference) scan's file coordinates, world "
    "coordinates when that file is georeferenced (its coordinate system)",
    "y_m": "stem base, m, as x_m",
    "z_m": "ground height at the stem base, m, as x_m",
    "height_m": "highest point of the tree above its base, m; empty where its top "
    "was out of every scan's range",
    "height_flag": "ok: nothing doubts it. "
    + " ".join(f"{flag}: {text}." for flag, text in HEIGHT_FLAGS.items()),
    "height_seen_m": "where the top was out of range: how high above its base the "
    "tree was seen, m (the tree is taller); empty otherwise",
    "dbh_m": "diameter at 1.3 m, m: the taper line through circles fitted from 1.0 "
    "to 1.6 m",
    "dbh_quality": f"ok: {DBH_OK}. check: {DBH_CHECK}. none: no DBH.",
    "dbh_arc_deg": "arc of the stem its breast-height points cover, degrees",
    "dbh_rmse_m": "RMS distance of those points from the circle, m",
    "dbh_outlier_share": f"0-1: {OUTLIER_SHARE}",
    "dbh_why": "why the DBH is check or none",
    "lean_deg": "lean of the stem line from the vertical, degrees; empty: not measured",
    "crown_width_m": "mean width of the crown across its two main axes, m",
    "n_points": "points of the tree in the merged plot, thinned to about 1 cm",
    "seen_from": "scans (numbered from 1) with points on the tree 0.3-2.5 m up",
    "scans_to_check": "of them, the scans whose pose needs review",
    "mark": "your mark: ok, check or not a tree",
    "dbh_hand_m": "your DBH, measured by hand in the app, m",
    "in_plot": "yes / no: the stem base within amrst plot --plot-radius; empty "
    "without one",
}


def run_files(out: Path) -> list[str]:
    """List the names in ``out`` a run writes (``trees/T….ply``: its tree clouds)."""
    theirs = sorted(n for n in MANAGED - {TREES_DIR} if os.path.lexists(out / n))
    if any((out / TREES_DIR).glob("T[0-9]*.ply")):  # a run's tree clouds' names
        theirs.append(f"{TREES_DIR}/T….ply")
    return theirs


def _refuse_results(out: Path) -> None:
    """Refuse a folder holding a plot, a run's files without one, or a registration's."""
    if (out / PLOT_JSON).exists():
        raise InvalidInput(
            f"{out} already holds a plot ({PLOT_JSON}): choose another results "
            "folder, or --overwrite to replace it."
        )
    theirs = run_files(out)
    if theirs:
        raise InvalidInput(
            f"{out} holds {', '.join(theirs)} but no plot ({PLOT_JSON}): a run would "
            "replace or remove them. Choose another results folder, or "
            "--overwrite to replace them."
        )
    from amrst.results.export import other_export

    theirs_too = other_export(out, [])  # amrst register's files
    if theirs_too:
        raise InvalidInput(
            f"{out} holds {theirs_too}: a plot's files beside it would mix two "
            "results. Choose another results folder, or --overwrite to write the "
            "plot beside it."
        )


def check_out(out: Path, overwrite: bool) -> None:
    """Refuse an output folder a run cannot write into.

    That is a file, a place that cannot be written, or a folder that holds another
    run's output, a plot's or a registration's (unless ``overwrite``). Its review must
    be readable (its marks go into the inventory). All refused before the run rather
    than after it, in words for the command line and the app alike (the folder is
    --out to one, a field to the other).
    """
    if out.is_symlink() and not out.exists():
        raise InvalidInput(
            f"{out} is a link to {os.readlink(out)}, which does not exist: fix the "
            "link or choose another results folder."
        )
    if out.exists() and not out.is_dir():
        raise InvalidInput(
            f"{out} is a file, not a folder: choose another results folder."
        )
    trees = out / TREES_DIR
    if os.path.lexists(trees) and not trees.is_dir():
        raise InvalidInput(
            f"{trees} is a file, where a run keeps its tree clouds: move it, or "
            "choose another results folder."
        )
    if not overwrite:
        _refuse_results(out)
    # Created (and removed again) to write a file in it: what permissions tell of
    # /proc or a full read-only mount is not what a write meets.
    check_output_folder(out, "results folder")
    read_review(out, ())


def trees_csv(
    trees: Sequence[Tree],
    review: PlotReview | None = None,
    area: PlotArea | None = None,
    unsure: Collection[int] = (),
) -> str:
    """Return trees.csv: one row per tree, the columns of ``INVENTORY_COLUMNS``."""
    return _csv_text(inventory_rows(trees, review or PlotReview(), area, unsure))


def _csv_text(rows: Sequence[Mapping[str, Any]]) -> str:
    buf = _stdio.StringIO()
    writer = csv.DictWriter(buf, fieldnames=INVENTORY_COLUMNS, lineterminator="\n")
    writer.writeheader()
    writer.writerows(rows)
    return buf.getvalue()


def write_inventory(
    out: Path,
    trees: Sequence[Tree],
    review: PlotReview,
    area: PlotArea | None,
    *,
    unsure: Collection[int],
) -> list[Path]:
    """Write trees.csv (and trees.xlsx) again with this review, as one unit.

    ``unsure``: the scans, from 1, that need review as the review leaves them.
    """
    from amrst.files.outdir import replace_files

    writers = _inventory_writers(inventory_rows(trees, review, area, unsure))
    written, _ = replace_files(out, writers, managed=MANAGED, lock_timeout_s=0)
    return written


def export_inventory(
    path: Path,
    trees: Sequence[Tree],
    review: PlotReview,
    area: PlotArea | None,
    *,
    unsure: Collection[int],
) -> None:
    """Write the inventory with the review to ``path`` (``.csv``/``.xlsx``), atomically.

    Raises
    ------
    InvalidInput
        Another extension, a missing folder, or ``.xlsx`` without openpyxl.
    """
    from amrst.files.atomic import write_atomic

    suffix = path.suffix.lower()
    if suffix not in (".csv", ".xlsx"):
        raise InvalidInput(
            f"Cannot export the inventory as {path.name}: name it .csv or .xlsx."
        )
    if not path.parent.is_dir():
        raise InvalidInput(f"Cannot write {path}: its folder does not exist.")
    writers = _inventory_writers(inventory_rows(trees, review, area, unsure))
    name = TREES_CSV if suffix == ".csv" else TREES_XLSX
    if name not in writers:
        raise InvalidInput(
            "Writing .xlsx needs openpyxl (pip install amrst-studio[campaign]); "
            "export as .csv instead."
        )
    write_atomic(path, writers[name])


def write_report(out: Path) -> Path:
    """Write ``report.html`` in ``out`` from its plot.json and trees.csv; return it.

    Raises
    ------
    InvalidInput
        The folder holds no readable plot.json and trees.csv (run the plot first).
    """
    from amrst.files.atomic import write_text_atomic
    from amrst.plot.report import build_report

    try:
        doc, rows = read_plot_json(out), read_tree_rows(out)
        page = build_report(doc, rows)
    except (OSError, ValueError, KeyError, TypeError, InvalidInput) as exc:
        raise InvalidInput(
            f"No report: {out} holds no readable plot ({exc}); run the plot again."
        ) from exc
    path = out / REPORT
    write_text_atomic(path, page)
    return path


@dataclass(frozen=True, slots=True)
class PlotFiles:
    """A plot's results folder read back: plot.json, the trees, the drawing."""

    doc: dict[str, Any]  # plot.json
    trees: tuple[Tree, ...]  # trees.csv's, in its order
    view: PlotView


def read_plot(out: Path) -> PlotFiles:
    """Read the results ``amrst plot`` (or the app) wrote into ``out``.

    Raises
    ------
    InvalidInput
        A file missing, unreadable, or not of one run (run the plot again).
    """
    from amrst.plot.inventory import Tree

    if not out.is_dir():
        raise InvalidInput(
            f"{out} {'is not a folder' if out.exists() else 'does not exist'}: "
            "choose the folder a plot was written into."
        )
    if not (out / PLOT_JSON).is_file():
        raise InvalidInput(
            f"{out} holds no plot ({PLOT_JSON}): choose the folder a plot was "
            "written into."
        )
    if not os.path.lexists(out / VIEW_NPZ):
        raise InvalidInput(
            f"{out} holds a plot, but its {VIEW_NPZ} (the drawing of its trees) is "
            "missing: run the plot again from its scans."
        )
    view = read_view(out / VIEW_NPZ)
    try:
        doc, rows = read_plot_json(out), read_tree_rows(out)
        if len(doc["scans"]) != len(view.offsets):
            raise ValueError(f"{len(doc['scans'])} scans, {VIEW_NPZ} draws another")
        reference = [s["label"] for s in doc["scans"]].index(doc["reference"])
        at = dict(zip(view.trees, view.dbh_xy, strict=True))
        # csv fills the cells a row lacks with None: a file cut off, or edited by
        # hand. (Its tree ids alone still tell which tree clouds a run wrote.)
        short = next((n for n, r in enumerate(rows, 1) if None in r.values()), None)
        if short is not None:
            raise ValueError(f"{TREES_CSV} row {short} has too few cells")
        trees = tuple(
            Tree.from_row(row, view.offsets[reference], at[row["tree_id"]])
            for row in rows
        )
        if [t.tree_id for t in trees] != list(view.trees):
            raise ValueError(f"{TREES_CSV} lists other trees than {VIEW_NPZ}")
    except (OSError, ValueError, KeyError, TypeError) as exc:
        raise InvalidInput(
            f"{out} holds no readable plot ({exc}): run the plot again from its scans."
        ) from exc
    return PlotFiles(doc, trees, view)


def _listed_ids(out: Path) -> list[str]:
    """Return the tree ids an earlier run's trees.csv in ``out`` lists.

    When it cannot be read, every tree cloud's id: the run was let replace the
    earlier one's files without knowing which they were.
    """
    ours = re.compile(r"[TH][0-9]+")  # what names a tree cloud, never a path
    try:
        ids = [r.get("tree_id") or "" for r in read_tree_rows(out)]
    except (OSError, ValueError):
        ids = [p.stem for p in (out / TREES_DIR).glob("*.ply")]
    return [i for i in ids if ours.fullmatch(i)]


def read_plot_json(out: Path) -> dict[str, Any]:
    """Return ``out``'s plot.json.

    Raises OSError or ValueError, with the reason, when it cannot be read: missing,
    not a regular file, not JSON, or not an object.
    """
    import json

    _regular_file(out / PLOT_JSON)
    doc = json.loads((out / PLOT_JSON).read_text(encoding="utf-8"))
    if not isinstance(doc, dict):
        raise ValueError(f"{PLOT_JSON} holds no object")
    return doc


def _regular_file(path: Path) -> None:
    """Refuse anything but a regular file: opening a named pipe would wait forever."""
    if os.path.lexists(path) and not path.is_file():
        raise ValueError(f"{path.name} is not a file (a folder, a named pipe...)")


def read_tree_rows(out: Path) -> list[dict[str, str]]:
    """Return the rows of ``out``'s trees.csv.

    Raises OSError or ValueError when it cannot be read. A trees.csv a spreadsheet
    saved again is read when only its byte-order mark or line ends changed; other
    changes (';' between the columns, another encoding) are named.
    """
    _regular_file(out / TREES_CSV)
    other = "another program saved it over"
    try:
        with (out / TREES_CSV).open(newline="", encoding="utf-8-sig") as fh:
            reader = csv.DictReader(fh)
            columns = reader.fieldnames or ()
            # These came later: a results folder of an earlier run lacks them.
            later = {"dbh_why", "height_seen_m"}
            missing = [c for c in TREE_COLUMNS if c not in {*columns, *later}]
            if missing:
                raise ValueError(f"{TREES_CSV} has no {missing[0]} column: {other}")
            return list(reader)
    except UnicodeDecodeError as exc:
        raise ValueError(f"{TREES_CSV} is not UTF-8 text: {other}") from exc
    except csv.Error as exc:
        raise ValueError(f"{TREES_CSV} is not a table ({exc}): {other}") from exc


def plot_document(
    reg: PlotRegistration,
    inventory: Inventory,
    labels: Sequence[str],
    review: PlotReview | None = None,
    pairs_files: Mapping[tuple[int, int], str] | None = None,
) -> dict[str, Any]:
    """Return plot.json's content: scans and poses, links, bundle, tree count.

    A scan's ``status`` is the registration's, its ``state`` that with the links
    the technician accepted (``review``); a link says whether it is one of those.
    ``unsure_links`` are the links, as ``[target, source]``, whose review the scan
    waits for (None: no one link to check, ``graph.scan_doubts``).
    A scan's ``name`` is its name in its file (an E57 setup's; "" when none).
    ``T_reference_scan`` maps the scan's file coordinates into the reference's (world
    coordinates when the files carry an offset), as ``amrst register`` writes it;
    ``scanner_xyz`` is where the scan's scanner stood in the reference's file
    coordinates (None: not placed, or a georeferenced file that does not say);
    ``scanner_given`` where the person running the plot said it stood, in the scan's
    own file coordinates (``amrst plot --scanner``; None: not given); ``turned``, for
    a scan that failed, how it seems to stand (``PlotRegistration.turned``); a
    link's ``T_target_source`` its source's into its target's. A link placed from
    point pairs names their file (``pairs_files``, keyed by the scans as its target
    and source points, from 0) as ``pairs``: the next run can place it again.
    """
    from amrst.types import world_transform

    clouds = [scan.analysis.cloud for scan in reg.scans]
    reference = clouds[reg.reference]
    accepted = (review or PlotReview()).accepted
    keep = reg.accepted(accepted)
    links = []
    for pl in reg.links:
        entry = pl.link.as_dict()
        entry["stems_shared"] = len(pl.shared)
        entry["residual_m"] = pl.residual_m
        entry["loop_confirmed"] = reg.loop_confirms(pl.link)
        entry["accepted"] = (pl.link.target, pl.link.source) in keep
        entry["pairs"] = next(
            (
                {"file": str(f), "target": i, "source": j}
                for (i, j), f in (pairs_files or {}).items()
                if {i, j} == {pl.link.target, pl.link.source}
            ),
            None,
        )
        entry["T_target_source"] = (
            None
            if pl.link.T_local is None
            else world_transform(
                pl.link.T_local, clouds[pl.link.target], clouds[pl.link.source]
            ).tolist()
        )
        links.append(entry)
    return {
        "amrst_version": __version__,
        "written_utc": _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="seconds"),
        "reference": labels[reg.reference],
        "scans": [
            {
                "label": label,
                "name": str(cloud.meta.get("scan_name", "")),
                "file_id": scan_id(label),
                "status": status,
                "state": state,
                "reached": pose is not None,
                "T_reference_scan": (
                    None
                    if pose is None
                    else world_transform(pose, reference, cloud).tolist()
                ),
                "scanner_xyz": _scanner_xyz(cloud, pose, reference),
                "scanner_given": (
                    [float(v) for v in cloud.meta["scanner_origin"]]
                    if cloud.meta.get("scanner_given")
                    else None
                ),
                "path": None if path is None else [k + 1 for k in path],
                "stems": len(scan.stems.stems),
                "turned": turned,
                "residual_m": residual,
                "unsure_links": None
                if doubts is None
                else sorted([t, s] for t, s in doubts),
            }
            for label, pose, path, scan, status, state, doubts, cloud, residual, turned in zip(
                labels,
                reg.poses,
                reg.paths,
                reg.scans,
                reg.statuses,
                reg.states(accepted),
                reg.doubts(),
                clouds,
                reg.residuals_m,
                reg.turned,
                strict=True,
            )
        ],
        "convention": "x_reference = T_reference_scan @ [x_scan, 1]; the files' "
        "coordinates, row-major, metres",
        "links": links,
        "bundle_rmse_m": reg.bundle_rmse_m,
        "joint": None if reg.joint is None else reg.joint.as_dict(),
        "loops": _loops(reg.loops),
        "trees": len(inventory.trees),
        "no_tree_why": inventory.why_none,
        "timings_s": {k: round(v, 3) for k, v in reg.timings.items()},
    }


def _scanner_xyz(
    cloud: Cloud, pose: Transform | None, reference: Cloud
) -> list[float] | None:
    at = scanner_in_reference(cloud, pose)
    return None if at is None else [float(v) for v in at + reference.offset]


def write_states(
    out: Path,
    states: Sequence[str],
    accepted: Collection[tuple[int, int]],
    trees: Sequence[Tree],
    review: PlotReview,
    area: PlotArea | None = None,
) -> None:
    """Write the scans' states and accepted links, and the inventory with them.

    plot.json takes the states and links, trees.csv its ``scans_to_check``; both are
    written as one unit. For a review made after the run (the app's Accept): the
    rest of plot.json stays what the run wrote.

    Raises
    ------
    InvalidInput
        No readable plot.json of that many scans in ``out``.
    """
    from amrst.files.outdir import replace_files

    path = out / PLOT_JSON
    try:
        doc = read_plot_json(out)
        scans, links = doc["scans"], doc["links"]
        if len(scans) != len(states):
            raise ValueError(f"{len(scans)} scans, not {len(states)}")
        for scan, state in zip(scans, states, strict=True):
            scan["state"] = state
        for link in links:
            link["accepted"] = (link["target"], link["source"]) in accepted
    except (OSError, ValueError, KeyError, TypeError) as exc:
        raise InvalidInput(
            f"{path} cannot take the review ({exc}); run the plot again."
        ) from exc
    text = _json_text(doc)
    rows = inventory_rows(trees, review, area, unsure_scans(states))
    writers = _inventory_writers(rows)
    writers[PLOT_JSON] = lambda p: p.write_text(text)
    replace_files(out, writers, managed=MANAGED, lock_timeout_s=0)


def write_area(
    out: Path, trees: Sequence[Tree], review: PlotReview, area: PlotArea | None
) -> None:
    """Give ``out``'s plot another fixed-radius plot (None: none), as one unit.

    plot.json's ``plot_area`` and trees.csv's ``in_plot`` change; the rest stays what
    the run wrote: the area counts trees, it moves none.

    Raises
    ------
    InvalidInput
        No readable plot.json in ``out``.
    """
    from amrst.files.outdir import replace_files

    path = out / PLOT_JSON
    try:
        doc = read_plot_json(out)
        doc["plot_area"] = None if area is None else area.as_dict()
        unsure = unsure_scans([scan["state"] for scan in doc["scans"]])
    except (OSError, ValueError, TypeError, KeyError) as exc:
        raise InvalidInput(
            f"{path} cannot take the plot area ({exc}); run the plot again."
        ) from exc
    text = _json_text(doc)
    writers = _inventory_writers(inventory_rows(trees, review, area, unsure))
    writers[PLOT_JSON] = lambda p: p.write_text(text)
    replace_files(out, writers, managed=MANAGED, lock_timeout_s=0)


def write_plot(
    out: Path,
    reg: PlotRegistration,
    inventory: Inventory,
    labels: Sequence[str],
    *,
    write_trees: bool = False,
    write_cloud: bool = False,
    report: bool = False,
    pairs_files: Mapping[tuple[int, int], str] | None = None,
    area: PlotArea | None = None,
    accepted: Mapping[tuple[int, int], Transform] | None = None,
    unchanged: FolderStamp | None = None,
) -> tuple[list[Path], list[str], list[str]]:
    """Write the run's files into ``out`` as one unit.

    Returns the files written, each scan's state as plot.json gives it (with the
    review the folder held when it was written), and the marks and DBHs of that
    review that found no tree at this run (dropped from it; ``review_lost`` in
    plot.json).

    ``labels`` name the scans as files and ``#k`` (:func:`amrst.io.scans.read_scans`).
    ``write_cloud``: also the registered plot, ``plot.laz`` (every point of every
    placed scan, read again from ``labels``, in the reference's frame, world
    coordinates, ``scan_id`` its number from 1). An earlier
    run's ``plot.laz`` and tree clouds that this run does not write again are removed,
    as they no longer match its poses and trees.
    ``report``: also ``report.html`` (``amrst.plot.report``). ``pairs_files``: the
    point pairs files the links placed by hand came from (:func:`plot_document`).
    ``area``: the fixed-radius plot, ``plot_area`` in plot.json (the report's stand
    figures count the trees inside it, per hectare). ``accepted``: links the
    technician accepts at these (world) poses, added to the folder's review.
    ``unchanged``: what ``out`` held when the run began; nothing is written when
    another run changed it since (:func:`amrst.files.outdir.folder_stamp`).
    """
    from amrst.files.atomic import strict_json
    from amrst.files.outdir import replace_files

    clouds = [scan.analysis.cloud for scan in reg.scans]
    reference = clouds[reg.reference]

    # The review follows its trees: a run that lists them otherwise moves it with them.
    # Read as it is now, not as the run began: the app may have changed it meanwhile.
    review, moved, lost = followed(
        read_review(out, labels),
        {t.tree_id: t.stem.dbh_xy for t in inventory.trees},
    )
    new = {
        key: T
        for key, T in (accepted or {}).items()
        if key not in review.accepted or not np.allclose(review.accepted[key], T)
    }
    if new:
        review = replace(review, accepted={**review.accepted, **new})
        moved = True
    doc = plot_document(reg, inventory, labels, review, pairs_files)
    doc["review_lost"] = lost  # the review that found no tree at this run
    doc["plot_area"] = None if area is None else area.as_dict()
    doc, _ = strict_json(doc)
    states = [scan["state"] for scan in doc["scans"]]
    rows = inventory_rows(inventory.trees, review, area, unsure_scans(states))
    writers = _inventory_writers(rows)
    writers[PLOT_JSON] = lambda p: p.write_text(_json_text(doc))
    writers[VIEW_NPZ] = view_writer(plot_view(clouds, inventory))
    if write_trees:
        for k, tree in enumerate(inventory.trees):
            writers[f"{TREES_DIR}/{tree.tree_id}.ply"] = _tree_writer(
                inventory.tree_points(k), reference
            )
    if write_cloud:
        writers[PLOT_CLOUD] = _plot_cloud_writer(reg, labels, inventory)
    if report:
        from amrst.plot.report import build_report

        page = build_report(doc, rows)
        writers[REPORT] = lambda p: p.write_text(page)
    # Files of an earlier run that this one does not write again no longer match it;
    # its tree clouds are those of the trees its trees.csv lists, other files stay.
    gone = [
        f"{TREES_DIR}/{tree_id}.ply"
        for tree_id in _listed_ids(out)
        if (out / TREES_DIR / f"{tree_id}.ply").is_file()
    ]
    gone += [] if write_cloud else [PLOT_CLOUD]
    gone += [] if report else [REPORT]
    written, _ = replace_files(
        out, writers, managed=MANAGED, remove=gone, unchanged=unchanged
    )
    if moved:
        write_review(out, labels, review)
    return written, states, lost


#: Every name a plot's run writes into its folder.
MANAGED = frozenset(
    {PLOT_JSON, TREES_CSV, TREES_XLSX, TREES_DIR, PLOT_CLOUD, REPORT, VIEW_NPZ}
)


def _plot_cloud_writer(
    reg: PlotRegistration, labels: Sequence[str], inventory: Inventory
) -> Callable[[Path], object]:
    """plot.laz: the placed scans read again and moved into the reference frame.

    The run kept only each scan's working points; reading the files again, one at a
    time, keeps memory at one scan as read. Each point's ``tree`` is the trees.csv
    row (from 1) of the tree owning the nearest working point within
    ``TREE_REACH_M``, 0 for none (ground, shrubs, what no tree owns); a point of no
    tree within the stem map's ``ground_dist_m`` of its ground is ground (class 2).
    """
    from amrst import io
    from amrst.io.scans import file_stamp, read_scans

    placed = [(k, pose) for k, pose in enumerate(reg.poses) if pose is not None]
    kept = [reg.scans[k] for k, _ in placed]

    def load(m: int) -> Cloud:
        k, scan = placed[m][0], kept[m]
        stamp = scan.file_stamp
        changed = stamp is not None and file_stamp(labels[k]) != stamp
        cloud = None if changed else read_scans(labels[k])[0]
        if cloud is None or (
            len(cloud) != scan.points_read
            or not np.array_equal(cloud.offset, scan.analysis.cloud.offset)
        ):
            raise InvalidInput(
                f"{labels[k]} changed while the plot ran: run the plot again."
            )
        return cloud

    parts = [scan.analysis.cloud for scan in kept]
    moves = [pose for _, pose in placed]
    ids = [k + 1 for k, _ in placed]
    offset = reg.scans[reg.reference].analysis.cloud.offset

    def write(path: Path) -> None:
        point_labels = _point_labeller(inventory)
        io.write_merged(path, parts, moves, offset, ids, load=load, labels=point_labels)

    return write


#: How far a point of plot.laz may lie from the working point that gives its tree (m).
TREE_REACH_M = 0.1


def _point_labeller(inventory: Inventory) -> PointLabels:
    """Each point's tree as plot.laz numbers it, and whether it is ground."""
    from amrst.neighbours import NearestTree
    from amrst.plot.stemmap import StemMapParams

    stem_map, ground_m = inventory.stem_map, StemMapParams().ground_dist_m
    number = np.r_[stem_map.owner + 1, 0]  # owner -1 (no tree) and no neighbour: 0
    tree = NearestTree(stem_map.xyz)

    def labels(xyz: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        _, nearest = tree.query(xyz, distance_upper_bound=TREE_REACH_M)
        trees = np.asarray(number[nearest])
        ground = np.zeros(len(xyz), dtype=bool)
        free = np.flatnonzero(trees == 0)  # a point a tree owns is never ground
        if stem_map.ground.found and len(free):
            ground[free] = np.abs(stem_map.ground.height(xyz[free])) < ground_m
        return trees, ground

    return labels


def _loops(loops: dict[str, float]) -> list[dict[str, Any]]:
    """Return the loop closures as plot.json's links name scans (from 0)."""
    pairs = ((key.split("-"), value) for key, value in loops.items())
    return [{"target": int(i), "source": int(j), "m": v} for (i, j), v in pairs]


def inventory_rows(
    trees: Sequence[Tree],
    review: PlotReview,
    area: PlotArea | None,
    unsure: Collection[int],
) -> list[dict[str, Any]]:
    """Return trees.csv's rows: the tree's figures, the technician's mark and DBH.

    ``scans_to_check`` lists the scans of ``seen_from`` that are ``unsure`` (numbered
    from 1, :func:`unsure_scans`): the tree's figures, even its being a tree, rest on
    a pose nobody confirmed yet. ``in_plot`` is ``yes`` or ``no`` for standing inside
    ``area`` (empty without one).
    """
    rows = []
    for t in trees:
        row = {
            **t.row(),
            "scans_to_check": ";".join(str(k) for k in t.seen_from if k in unsure),
            "mark": review.marks.get(t.tree_id, ""),
            "dbh_hand_m": _hand(review, t),
        }
        row["in_plot"] = "" if area is None else ("yes" if area.holds(row) else "no")
        rows.append(row)
    return rows


def _hand(review: PlotReview, tree: Tree) -> float | str:
    circle = review.dbh.get(tree.tree_id)
    return "" if circle is None else round(circle.dbh_m, 3)


def _inventory_writers(
    rows: Sequence[Mapping[str, Any]],
) -> dict[str, Callable[[Path], object]]:
    """trees.csv's writer, and trees.xlsx's when openpyxl is installed."""
    from amrst.files.atomic import xlsx_book

    text = _csv_text(rows)
    writers: dict[str, Callable[[Path], object]] = {
        TREES_CSV: lambda p: p.write_text(text)
    }
    book = xlsx_book("trees", INVENTORY_COLUMNS, rows, f"AMRST {__version__}")
    if book is not None:
        notes = book.create_sheet("columns")
        notes.append(["column", "meaning"])
        for column in INVENTORY_COLUMNS:
            notes.append([column, COLUMN_NOTES[column]])
        writers[TREES_XLSX] = book.save
    return writers


def _json_text(doc: Any) -> str:
    import json

    return json.dumps(doc, indent=2) + "\n"


def _tree_writer(points: np.ndarray, reference: Cloud) -> Callable[[Path], object]:
    from amrst import io
    from amrst.types import Cloud

    def write(path: Path) -> None:
        path.parent.mkdir(parents=True, exist_ok=True)
        io.write(path, Cloud(points, offset=reference.offset))

    return write
