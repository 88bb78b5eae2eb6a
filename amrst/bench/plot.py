"""``amrst bench`` on plot cases: every scan's pose and the inventory against the truth.

A plot case is a folder with the scans of one plot (``target.ply`` + ``source.ply``,
or ``scan_1.ply`` ... ``scan_N.ply``) and a ``truth.json`` with ``T_scan1_scank``
(scan k into scan 1) and ``stems_target_frame`` (every tree: ``x``, ``y``,
``z_base``, ``dbh_m``, ``height_m`` in scan 1's frame). On each case, read once:

- ``amrst plot`` registers all scans (timed: the registration, clouds in memory) and
  takes the inventory (timed apart);
- the baselines register every other scan on scan 1, the same pairs for each:
  KISS-Matcher (0.2 m voxel) + GICP, and FPFH + RANSAC (their ``timings["total"]``).

A scan is registered within 1 deg and 5 cm (``TruthErrors.registered``). A listed tree
is found when its stem base lies within 0.5 m of a true stem, each true stem matched
once, closest pairs first. The pair time of a method is its time on the case over the
number of scans placed on scan 1.
"""

from __future__ import annotations

import json
import logging
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from amrst.errors import AmrstError, Cancelled, InvalidInput

logger = logging.getLogger(__name__)

if TYPE_CHECKING:
    import os
    from collections.abc import Mapping, Sequence

    from amrst.plot.register import PlotRegistration
    from amrst.progress import Reporter
    from amrst.types import Cloud, Transform

#: A listed tree is a true one within this horizontal distance of its base (m).
FOUND_M = 0.5
#: A true tree is in view when a scan holds this many points on its lower stem:
#: within its radius + ``IN_VIEW_MARGIN_M`` of the base, 0.5-2 m above it.
IN_VIEW_POINTS = 20
IN_VIEW_MARGIN_M = 0.1
#: The baselines, as the summary names them.
KISS, FPFH = "kiss_gicp_0.2", "fpfh_ransac"
PLOT = "amrst_plot"
METHOD_NAMES = (PLOT, KISS, FPFH)
NAN = float("nan")


@dataclass(frozen=True, slots=True)
class PlotCase:
    """One plot case: its scans (scan 1 first), their true poses and the true trees.

    ``stems`` rows: x, y, z_base, dbh_m, height_m (scan 1's frame; DBH NaN where the
    truth has none).
    """

    name: str
    clouds: tuple[Cloud, ...]
    T_scan1_scank: tuple[Transform, ...]
    stems: np.ndarray


def is_plot_case(folder: str | os.PathLike[str]) -> bool:
    """Tell whether ``folder`` holds a plot case (its truth has the stem list)."""
    path = Path(folder) / "truth.json"
    if not path.is_file():
        return False
    try:
        doc = json.loads(path.read_text())
    except (OSError, ValueError):
        return False
    return (
        isinstance(doc, dict) and "T_scan1_scank" in doc and "stems_target_frame" in doc
    )


#: What each true stem in ``stems_target_frame`` gives: ``PlotCase.stems``' columns.
STEM_KEYS = ("x", "y", "z_base", "dbh_m", "height_m")
_STEMS_HINT = (
    "each stem must be an object with numbers x, y, z_base, height_m and dbh_m "
    "(null where unknown)"
)


def read_plot_truth(folder: str | os.PathLike[str]) -> tuple[list[Any], np.ndarray]:
    """Read a plot case's truth: the listed poses, and the true stems checked.

    Parameters
    ----------
    folder : path
        A plot case folder (its ``truth.json`` has ``T_scan1_scank`` and
        ``stems_target_frame``).

    Returns
    -------
    poses : list
        ``T_scan1_scank`` as read (:func:`read_plot_case` checks each is rigid).
    stems : (T, 5) float64
        Rows of ``STEM_KEYS``; DBH NaN where the truth has none.

    Raises
    ------
    InvalidInput
        If ``truth.json`` is unreadable, or its poses are not a list, or a stem is
        not an object of finite numbers (DBH: a number or null).
    """
    from amrst.files.safefile import load_json_file

    path = Path(folder) / "truth.json"
    doc = load_json_file(
        path, "truth file", "a JSON object with T_scan1_scank and stems_target_frame"
    )
    poses = doc.get("T_scan1_scank") if isinstance(doc, dict) else None
    if not isinstance(poses, list):
        raise InvalidInput(
            f"{path}: T_scan1_scank must be a list of 4x4 poses, one per scan "
            "(scan k into scan 1, row-major)."
        )
    entries = doc.get("stems_target_frame")
    if not isinstance(entries, list):
        raise InvalidInput(
            f"{path}: stems_target_frame must be a list of stems; {_STEMS_HINT}."
        )
    rows = [_stem_row(s, i, path) for i, s in enumerate(entries, start=1)]
    return poses, np.array(rows, dtype=float).reshape(-1, len(STEM_KEYS))


def _stem_row(stem: object, index: int, path: Path) -> list[float]:
    """One stem of the truth as numbers in ``STEM_KEYS`` order; refuse a bad one."""
    where = f"{path}: stem {index} of stems_target_frame"
    if not isinstance(stem, dict):
        raise InvalidInput(f"{where} is {json.dumps(stem)[:40]}; {_STEMS_HINT}.")
    row = []
    for key in STEM_KEYS:
        if key not in stem:
            raise InvalidInput(f"{where} has no {key}; {_STEMS_HINT}.")
        value = stem[key]
        if key == "dbh_m" and value is None:
            row.append(NAN)
            continue
        numeric = isinstance(value, int | float) and not isinstance(value, bool)
        # Integers too large for a float count as not finite.
        number = float(value) if numeric and abs(value) < 1e300 else NAN
        # A DBH may be NaN, as the simulator writes an unknown one; no other value.
        unknown_dbh = key == "dbh_m" and numeric and value != value
        if not (np.isfinite(number) or unknown_dbh):
            raise InvalidInput(
                f"{where} has {key} {json.dumps(value)[:40]}, not a finite number; "
                f"{_STEMS_HINT}."
            )
        row.append(number)
    return row


def read_plot_case(folder: str | os.PathLike[str]) -> PlotCase:
    """Read one plot case folder.

    Raises
    ------
    InvalidInput
        A missing scan, fewer than two scans, a truth that does not match them, or
        a truth :func:`read_plot_truth` refuses.
    """
    from amrst import io
    from amrst.io.cases import plot_scan_files
    from amrst.types import check_rigid

    root = Path(folder)
    poses, stems = read_plot_truth(root)
    files = plot_scan_files(root)
    if len(files) < 2 or len(files) != len(poses):
        raise InvalidInput(
            f"{root}: {len(files)} scan files for {len(poses)} poses in truth.json; "
            "a plot case holds target.ply + source.ply or scan_1.ply ... scan_N.ply, "
            "one pose per scan."
        )
    for p in files:
        if not p.is_file():
            raise InvalidInput(f"{root}: {p.name} is missing.")
    return PlotCase(
        root.name,
        tuple(io.read(p) for p in files),
        tuple(check_rigid(T, f"T_scan1_scank in {root}") for T in poses),
        stems,
    )


@dataclass(frozen=True, slots=True)
class InventoryScore:
    """A listed inventory against the true trees (see :func:`score_inventory`)."""

    n_true: int
    found: int
    in_view: int  # true trees some scan sees (see ``trees_in_view``)
    found_in_view: int
    listed: int
    real: int
    dbh_errors_m: tuple[float, ...]  # listed minus true, both defined
    dbh_ok_errors_m: tuple[float, ...]  # the same, trees whose DBH is flagged ok
    dbh_missing: int  # found trees with a true DBH but none listed
    height_errors_m: tuple[float, ...]
    height_ok_errors_m: tuple[float, ...] = ()  # trees whose height is flagged ok
    height_missing: int = 0  # found trees listed with no height


def match_trees(listed_xy: np.ndarray, true_xy: np.ndarray) -> list[tuple[int, int]]:
    """Pair listed and true trees within ``FOUND_M``, each once, closest first."""
    if not len(listed_xy) or not len(true_xy):
        return []
    d = np.hypot(
        listed_xy[:, None, 0] - true_xy[None, :, 0],
        listed_xy[:, None, 1] - true_xy[None, :, 1],
    )
    pairs = []
    used_l: set[int] = set()
    used_t: set[int] = set()
    for flat in np.argsort(d, axis=None):
        i, j = divmod(int(flat), d.shape[1])
        if d[i, j] > FOUND_M:
            break
        if i not in used_l and j not in used_t:
            used_l.add(i)
            used_t.add(j)
            pairs.append((i, j))
    return pairs


def trees_in_view(case: PlotCase) -> np.ndarray:
    """(T,) bool: the true trees whose lower stem some scan holds points of.

    A tree behind others or beyond every scan's range cannot be found; the share of
    trees found is also given over the trees in view.
    """
    seen = np.zeros(len(case.stems), dtype=bool)
    for cloud, T in zip(case.clouds, case.T_scan1_scank, strict=True):
        xyz = cloud.xyz @ T[:3, :3].T + T[:3, 3]
        for j, (x, y, z, dbh, _h) in enumerate(case.stems):
            r = (dbh / 2 if np.isfinite(dbh) else 0.15) + IN_VIEW_MARGIN_M
            h = xyz[:, 2] - z
            near = (np.hypot(xyz[:, 0] - x, xyz[:, 1] - y) <= r) & (h >= 0.5) & (h <= 2)
            seen[j] |= int(near.sum()) >= IN_VIEW_POINTS
    return seen


def score_inventory(
    listed: np.ndarray,
    quality: Sequence[str],
    truth: np.ndarray,
    height_flags: Sequence[str] | None = None,
    in_view: np.ndarray | None = None,
) -> InventoryScore:
    """Score listed trees (rows x, y, z, dbh_m, height_m) against the true ones.

    ``quality``: each listed tree's DBH flag; ``height_flags``: its height flag
    (None: all ok); ``in_view``: which true trees a scan sees (None: all).
    """
    flags = height_flags if height_flags is not None else ["ok"] * len(listed)
    listed = np.asarray(listed, dtype=float).reshape(-1, 5)
    pairs = match_trees(listed[:, :2], truth[:, :2])
    dbh, dbh_ok, heights, heights_ok = [], [], [], []
    missing = height_missing = 0
    for i, j in pairs:
        if np.isfinite(truth[j, 3]):
            if np.isfinite(listed[i, 3]):
                dbh.append(float(listed[i, 3] - truth[j, 3]))
                if quality[i] == "ok":
                    dbh_ok.append(dbh[-1])
            else:
                missing += 1
        if np.isfinite(listed[i, 4]):
            heights.append(float(listed[i, 4] - truth[j, 4]))
            if flags[i] == "ok":
                heights_ok.append(heights[-1])
        else:
            height_missing += 1
    seen = np.ones(len(truth), bool) if in_view is None else np.asarray(in_view)
    return InventoryScore(
        n_true=len(truth),
        found=len(pairs),
        in_view=int(seen.sum()),
        found_in_view=sum(int(seen[j]) for _i, j in pairs),
        listed=len(listed),
        real=len(pairs),
        dbh_errors_m=tuple(dbh),
        dbh_ok_errors_m=tuple(dbh_ok),
        dbh_missing=missing,
        height_errors_m=tuple(heights),
        height_ok_errors_m=tuple(heights_ok),
        height_missing=height_missing,
    )


@dataclass(slots=True)
class PlotRecord:
    """One method on one plot case: per-scan truth errors and time per scan placed."""

    case: str
    method: str
    n_scans: int
    registered: int = 0  # scans 2..N within 1 deg / 5 cm
    rotation_error_deg: list[float] = field(default_factory=list)
    translation_error_m: list[float] = field(default_factory=list)
    gt_rmse_m: list[float] = field(default_factory=list)
    time_s: float = NAN  # registration of all scans
    pair_s: float = NAN  # time_s over the scans but the reference: a pair for two
    inventory_s: float = NAN
    inventory: InventoryScore | None = None
    origins: list[str] = field(default_factory=list)  # plot: each link's source
    #: Scans 2..N the method itself flags (plot: not registered); a scan off the
    #: truth and not flagged is a silent failure. The peers flag nothing.
    flagged: list[bool] = field(default_factory=list)
    silent: int = 0
    #: amrst plot: each scan's residual at its poses, and the last scan's at the
    #: true poses and with that scan moved by ``OFF_DEG`` and ``OFF_M`` (m).
    residuals_m: list[float] = field(default_factory=list)
    residual_true_m: float = NAN
    residual_off_m: float = NAN
    error: str = ""

    def as_dict(self) -> dict[str, Any]:
        """Plain dict for JSON."""
        return asdict(self)


def _score_poses(
    case: PlotCase, record: PlotRecord, poses: Sequence[Transform | None]
) -> None:
    from amrst.stages.metrics import truth_errors

    for k in range(1, len(case.clouds)):
        T = poses[k]
        if T is None:
            for values in (
                record.rotation_error_deg,
                record.translation_error_m,
                record.gt_rmse_m,
            ):
                values.append(NAN)
            continue
        e = truth_errors(T, case.T_scan1_scank[k], case.clouds[k].xyz)
        record.rotation_error_deg.append(e.rotation_error_deg)
        record.translation_error_m.append(e.translation_error_m)
        record.gt_rmse_m.append(e.gt_rmse_m)
        record.registered += int(e.registered())
        flagged = bool(record.flagged) and record.flagged[k - 1]
        record.silent += int(not e.registered() and not flagged)


#: How far the residual check moves the last scan off its true pose: a turn about
#: the vertical through the scan's centre, and a shift along x.
OFF_DEG = 1.0
OFF_M = 0.1


def _score_residuals(case: PlotCase, record: PlotRecord, reg: PlotRegistration) -> None:
    """Record the residuals at amrst's poses, and whether they tell a pose off."""
    from scipy.spatial.transform import Rotation

    from amrst.plot.residual import Surfaces, scan_residuals
    from amrst.types import make_transform

    record.residuals_m = list(reg.residuals_m)
    points = [s.analysis.cloud.xyz for s in reg.scans]
    surfaces = Surfaces(points)
    truth = [np.asarray(T, dtype=float) for T in case.T_scan1_scank]
    turn = Rotation.from_euler("z", OFF_DEG, degrees=True).as_matrix()
    centre = truth[-1][:3, :3] @ points[-1].mean(axis=0) + truth[-1][:3, 3]
    move = make_transform(turn, centre - turn @ centre + np.array([OFF_M, 0, 0]))
    off = [*truth[:-1], move @ truth[-1]]
    record.residual_true_m = scan_residuals(surfaces, truth)[-1]
    record.residual_off_m = scan_residuals(surfaces, off)[-1]


def _local(case: PlotCase) -> PlotCase:
    """Return the case with every scan in scan 1's local frame (as its truth)."""
    from amrst.types import Cloud

    origin = np.asarray(case.clouds[0].offset, dtype=float)
    clouds = tuple(
        Cloud(c.xyz + (np.asarray(c.offset, dtype=float) - origin), name=c.name)
        for c in case.clouds
    )
    return PlotCase(case.name, clouds, case.T_scan1_scank, case.stems)


def run_plot(case: PlotCase) -> PlotRecord:
    """Register and inventory the plot with ``amrst plot``'s engine; score both."""
    from amrst.plot.inventory import take_inventory
    from amrst.plot.register import analyse_plot, register_plot
    from amrst.review.verdict import REGISTERED

    n = len(case.clouds)
    record = PlotRecord(case.name, PLOT, n)
    t0 = time.perf_counter()
    reg = register_plot(analyse_plot(case.clouds))
    record.time_s = time.perf_counter() - t0
    record.pair_s = record.time_s / (n - 1)
    record.origins = [pl.link.origin for pl in reg.links if pl.link.in_tree]
    record.flagged = [status != REGISTERED for status in reg.statuses[1:]]
    _score_poses(case, record, reg.poses)
    _score_residuals(case, record, reg)
    t0 = time.perf_counter()
    inv = take_inventory([s.analysis.cloud for s in reg.scans], reg.poses)
    record.inventory_s = time.perf_counter() - t0
    listed = np.array(
        [[*t.stem.base, t.stem.dbh_m, t.stem.height_m] for t in inv.trees]
    ).reshape(-1, 5)
    record.inventory = score_inventory(
        listed,
        [t.stem.dbh_quality for t in inv.trees],
        case.stems,
        [t.stem.height_flag for t in inv.trees],
        trees_in_view(case),
    )
    return record


def run_baseline(case: PlotCase, name: str) -> PlotRecord:
    """Register every scan on scan 1 with one baseline; score the poses."""
    from amrst.baselines import (
        KissParams,
        register_fpfh_ransac,
        register_kiss_gicp,
    )

    n = len(case.clouds)
    record = PlotRecord(case.name, name, n)
    poses: list[Transform | None] = [np.eye(4)]
    total = 0.0
    for k in range(1, n):
        if name == KISS:
            res = register_kiss_gicp(
                case.clouds[0], case.clouds[k], KissParams(voxel_size_m=0.2)
            )
        else:
            res = register_fpfh_ransac(case.clouds[0], case.clouds[k])
        total += float(res.timings["total"])
        poses.append(np.asarray(res.T_target_source, dtype=float))
    record.time_s = total
    record.pair_s = total / (n - 1)
    _score_poses(case, record, poses)
    return record


def _run_guarded(case: PlotCase, name: str) -> PlotRecord:
    """Run one method; an exception becomes the record's error (the run goes on)."""
    try:
        return run_plot(case) if name == PLOT else run_baseline(case, name)
    except Cancelled:
        raise
    except Exception as exc:  # one failing method must not stop the benchmark
        text = (
            str(exc) if isinstance(exc, AmrstError) else f"{type(exc).__name__}: {exc}"
        )
        return PlotRecord(case.name, name, len(case.clouds), error=text)


def run_plot_bench(
    cases_dir: str | os.PathLike[str],
    out_dir: str | os.PathLike[str] = "bench_out",
    reporter: Reporter | None = None,
    *,
    pattern: str | None = None,
    methods: Sequence[str] = METHOD_NAMES,
) -> list[PlotRecord]:
    """Run ``amrst plot`` and the baselines on every plot case; write the summary.

    Writes ``plot_results.json`` and ``summary.md`` into ``out_dir`` after every case.
    ``methods``: some of ``METHOD_NAMES``.

    Raises
    ------
    InvalidInput
        No plot case under ``cases_dir``, or one whose truth
        :func:`read_plot_truth` refuses (before anything runs).
    """
    from amrst.bench.run import warm_up
    from amrst.files.atomic import make_folder, write_json_atomic, write_text_atomic
    from amrst.io.cases import find_cases

    unknown = sorted(set(methods) - set(METHOD_NAMES))
    if unknown:
        raise InvalidInput(
            f"Unknown plot method(s) {unknown}; choose from {METHOD_NAMES}."
        )
    folders = [f for f in find_cases(cases_dir, pattern) if is_plot_case(f)]
    if not folders:
        raise InvalidInput(
            f"No plot case folders under {cases_dir}: each needs its scans and a "
            "truth.json with T_scan1_scank and stems_target_frame."
        )
    for folder in folders:  # a bad truth is told before any case runs
        read_plot_truth(folder)
    out = make_folder(out_dir, "output folder")
    warm_up(["amrst", "fpfh_ransac"])
    records: list[PlotRecord] = []
    skipped: dict[str, str] = {}
    for i, folder in enumerate(folders):
        try:
            case = _local(read_plot_case(folder))
        except AmrstError as exc:  # one unreadable case must not stop the benchmark
            logger.warning("Plot case %s skipped: %s", folder.name, exc)
            skipped[folder.name] = str(exc)
            write_text_atomic(out / "summary.md", plot_summary(records, skipped))
            continue
        for name in methods:
            if reporter is not None:
                reporter.check_cancelled()
                reporter.progress(
                    i / len(folders),
                    f"case {i + 1}/{len(folders)} {case.name} | {name}",
                )
            records.append(_run_guarded(case, name))
        write_json_atomic(out / "plot_results.json", [r.as_dict() for r in records])
        write_text_atomic(out / "summary.md", plot_summary(records, skipped))
    if not records:
        name, why = next(iter(skipped.items()))
        raise InvalidInput(f"No plot case could be read ({name}: {why})")
    if reporter is not None:
        reporter.progress(1.0, "done")
    return records


def _fmt(value: float, scale: float = 1.0, digits: int = 2) -> str:
    return "-" if not np.isfinite(value) else f"{scale * value:.{digits}f}"


def _worst(values: Sequence[float]) -> float:
    a = np.asarray(values, dtype=float)
    return NAN if not len(a) or np.isnan(a).any() else float(a.max())


def _rms(values: Sequence[float]) -> float:
    return NAN if not values else float(np.sqrt(np.mean(np.square(values))))


def _median_abs(values: Sequence[float]) -> float:
    return NAN if not values else float(np.median(np.abs(values)))


def _registration_table(records: Sequence[PlotRecord]) -> list[str]:
    cases = list(dict.fromkeys(r.case for r in records))
    names = [m for m in METHOD_NAMES if any(r.method == m for r in records)]
    by = {(r.case, r.method): r for r in records}
    head = "| case | scans |" + "".join(
        f" {m}: ok, worst deg / cm, s a scan placed |" for m in names
    )
    lines = [head, "|---|---|" + "---|" * len(names)]
    for c in cases:
        cells = []
        for m in names:
            r = by.get((c, m))
            if r is None or r.error:
                cells.append(f" failed: {r.error[:60] if r else '-'} |")
                continue
            cells.append(
                f" {r.registered}/{r.n_scans - 1}, "
                f"{_fmt(_worst(r.rotation_error_deg), digits=3)} / "
                f"{_fmt(_worst(r.gt_rmse_m), 100, 1)}, {_fmt(r.pair_s)} |"
            )
        n = next(r.n_scans for r in records if r.case == c)
        lines.append(f"| {c} | {n} |" + "".join(cells))
    lines.append("")
    for m in names:
        rs = [r for r in records if r.method == m and not r.error]
        ok = sum(r.registered for r in rs)
        total = sum(r.n_scans - 1 for r in records if r.method == m)
        med = np.median([r.pair_s for r in rs]) if rs else NAN
        silent = sum(r.silent for r in rs)
        flagged = sum(sum(r.flagged) for r in rs)
        lines.append(
            f"- {m}: {ok}/{total} scans registered; median time a scan placed "
            f"{_fmt(float(med))} s"
            + (f"; flagged {flagged}, silent failures {silent}" if m == PLOT else "")
        )
    return lines


def _inventory_table(records: Sequence[PlotRecord]) -> list[str]:
    rows = [r for r in records if r.method == PLOT and r.inventory is not None]
    lines = [
        "| case | true trees | in view | found | listed | real | DBH RMSE cm (n) | "
        "DBH RMSE ok cm (n) | DBH missing | median height error m | "
        "the same, heights ok (n) | inventory s |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for r, s in ((r, r.inventory) for r in rows):
        if s is None:
            continue
        lines.append(
            f"| {r.case} | {s.n_true} | {s.in_view} | {s.found} | {s.listed} | "
            f"{s.real} | "
            f"{_fmt(_rms(s.dbh_errors_m), 100, 1)} ({len(s.dbh_errors_m)}) | "
            f"{_fmt(_rms(s.dbh_ok_errors_m), 100, 1)} ({len(s.dbh_ok_errors_m)}) | "
            f"{s.dbh_missing} | {_fmt(_median_abs(s.height_errors_m))} | "
            f"{_fmt(_median_abs(s.height_ok_errors_m))} "
            f"({len(s.height_ok_errors_m)}) | "
            f"{_fmt(r.inventory_s, digits=1)} |"
        )
    scores = [r.inventory for r in rows if r.inventory is not None]
    if scores:
        true = sum(s.n_true for s in scores)
        found = sum(s.found for s in scores)
        in_view = sum(s.in_view for s in scores)
        found_in_view = sum(s.found_in_view for s in scores)
        listed = sum(s.listed for s in scores)
        dbh = [e for s in scores for e in s.dbh_errors_m]
        dbh_ok = [e for s in scores for e in s.dbh_ok_errors_m]
        heights = [e for s in scores for e in s.height_errors_m]
        heights_ok = [e for s in scores for e in s.height_ok_errors_m]
        lines += [
            "",
            f"- trees found: {found}/{true} = {found / max(true, 1):.0%}; of the "
            f"trees in view {found_in_view}/{in_view} = "
            f"{found_in_view / max(in_view, 1):.0%}; listed trees real: "
            f"{found}/{listed} = {found / max(listed, 1):.0%}",
            f"- DBH RMSE {_fmt(_rms(dbh), 100)} cm over {len(dbh)} trees "
            f"({_fmt(_rms(dbh_ok), 100)} cm over the {len(dbh_ok)} flagged ok); "
            f"{sum(s.dbh_missing for s in scores)} found trees with a true DBH "
            "have none listed",
            f"- median height error {_fmt(_median_abs(heights))} m over "
            f"{len(heights)} trees ({_fmt(_median_abs(heights_ok))} m over the "
            f"{len(heights_ok)} flagged ok); "
            f"{sum(s.height_missing for s in scores)} found trees have no height "
            "(top out of range, or not measured)",
        ]
    return lines


def _residual_table(records: Sequence[PlotRecord]) -> list[str]:
    rows = [r for r in records if r.method == PLOT and not r.error]
    lines = [
        "| case | each scan at amrst's poses, cm | last scan at the truth, cm | "
        f"moved {OFF_DEG:g} deg / {100 * OFF_M:g} cm, cm |",
        "|---|---|---|---|",
    ]
    for r in rows:
        each = " ".join(_fmt(v, 100, 1) for v in r.residuals_m)
        lines.append(
            f"| {r.case} | {each} | {_fmt(r.residual_true_m, 100, 1)} | "
            f"{_fmt(r.residual_off_m, 100, 1)} |"
        )
    ratios = [
        r.residual_off_m / r.residual_true_m
        for r in rows
        if np.isfinite(r.residual_off_m) and r.residual_true_m > 0
    ]
    if ratios:
        lines += [
            "",
            f"- moved {OFF_DEG:g} deg / {100 * OFF_M:g} cm, the last scan's residual "
            f"is {np.median(ratios):.1f}x its residual at the truth (median over "
            f"cases; {min(ratios):.1f}-{max(ratios):.1f}x)",
        ]
    return lines


def plot_summary(
    records: Sequence[PlotRecord], skipped: Mapping[str, str] | None = None
) -> str:
    """Markdown: the per-case registration table and the inventory table.

    ``skipped``: the cases that could not be read, and why.
    """
    unread = [f"- {name} skipped: {why}" for name, why in (skipped or {}).items()]
    return "\n".join(
        [
            "# Plot benchmark",
            "",
            "Registration: scans within 1 deg / 5 cm of the truth, worst rotation "
            "error and gt_rmse of the case's scans, time a scan placed (the "
            "registration's time over the scans but the reference: a pair's for two "
            "scans; amrst plot registers every pair of scans, the peers each scan "
            "onto scan 1).",
            "",
            *_registration_table(records),
            "",
            "## Inventory (amrst plot)",
            "",
            *_inventory_table(records),
            "",
            "## Scan residuals (amrst plot)",
            "",
            "Each scan's RMS distance to the other scans' surfaces where they overlap.",
            "",
            *_residual_table(records),
            "",
            *([*unread, ""] if unread else []),
        ]
    )
