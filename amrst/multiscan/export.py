"""Write a multi-scan registration: the files ``amrst register`` writes, plus scans.json.

Two scans: exactly the pair files (transform.json/.txt, metrics.json/.csv,
params.json, and the clouds on request) through :func:`amrst.results.export.export_registration`.
More scans: ``transform.json`` lists every scan's 4x4 ``T_reference_scan`` (world frame),
its path and scanner origin; ``transform_<k>.txt`` holds scan k's 4x4; metrics.json /
metrics.csv hold every link, the joint refinement and the tree measures; params.json;
``merged.<fmt>`` (all reached scans, ``scan_id`` = scan number) on request. All of them
are staged and renamed into place together (amrst.results.export's staging folder).

Both write ``scans.json`` with them: the same summary for any number of scans
(``status``: registered, needs review or failed; links, paths, per-scan transforms, tree
measures), which the campaign table reads; and ``report.html`` on request.
"""

from __future__ import annotations

import csv
import io as _stdio
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from amrst import __version__
from amrst.files.atomic import text_writer, write_json_atomic, write_text_atomic
from amrst.types import Cloud, invert_transform

if TYPE_CHECKING:
    import os
    from collections.abc import Callable, Sequence

    from amrst.files.outdir import FolderStamp
    from amrst.multiscan.register import MultiScanResult
    from amrst.types import Transform

SUMMARY = "scans.json"


def _truth_errors(
    result: MultiScanResult, truth: Sequence[Transform | None] | None
) -> list[dict[str, Any] | None]:
    from amrst.stages.metrics import truth_errors

    if truth is None:
        return [None] * len(result.scans)
    out: list[dict[str, Any] | None] = []
    for k, (T, T_true) in enumerate(zip(result.T_reference_scan, truth, strict=True)):
        if T is None or T_true is None:
            out.append(None)
            continue
        src = result.scans[k].world_xyz
        err = truth_errors(T, np.asarray(T_true, float), src)
        row = {**err.as_dict(), "registered": err.registered()}
        T_tree = result.T_tree[k]
        if T_tree is not None:
            row["tree_gt_rmse_m"] = truth_errors(
                T_tree, np.asarray(T_true), src
            ).gt_rmse_m
        out.append(row)
    return out


def summary(
    result: MultiScanResult,
    truth: Sequence[Transform | None] | None = None,
    files: Sequence[str] = (),
) -> dict[str, Any]:
    """Return the scans.json content: state, links, paths, transforms, measures.

    Parameters
    ----------
    result : MultiScanResult
    truth : sequence of (4, 4) float64 or None, optional
        True ``T_reference_scan`` of each scan (world frame): adds truth errors.
    files : sequence of str
        The scan specs as given (file names, ``plot.e57#2``).
    """
    errors = _truth_errors(result, truth)
    scans = []
    for k, cloud in enumerate(result.scans):
        T = result.T_reference_scan[k]
        origin = result.origins[k] if k < len(result.origins) else None
        moved_origin = None
        if T is not None and origin is not None:
            moved_origin = (T[:3, :3] @ np.asarray(origin) + T[:3, 3]).tolist()
        scans.append(
            {
                "index": k,
                "name": cloud.name,
                "file": files[k] if k < len(files) else cloud.meta.get("path", ""),
                "reached": T is not None,
                "path": None
                if result.paths[k] is None
                else list(result.paths[k] or ()),
                "T_reference_scan": None if T is None else T.tolist(),
                "scanner_origin": moved_origin,
                "n_points": len(cloud),
                "truth": errors[k],
            }
        )
    tree_links = [link for link in result.links if link.in_tree and link.metrics]
    rmse = [link.metrics.rmse_overlap_m for link in tree_links if link.metrics]
    overlap = [link.metrics.overlap_fraction for link in tree_links if link.metrics]
    return {
        "status": result.status,
        "confidence": result.confidence,
        "reference": result.reference,
        "n_scans": len(result.scans),
        "n_reached": int(sum(result.reached)),
        "links_verified": sum(link.verified for link in result.links),
        "links_total": len(result.links),
        "rmse_overlap_m": max(rmse) if rmse else float("nan"),
        "overlap_fraction": min(overlap) if overlap else float("nan"),
        "scans": scans,
        "links": [link.as_dict() for link in result.links],
        "joint": None if result.joint is None else result.joint.as_dict(),
        "loops_m": result.loops,
        "tree": {k: v.as_dict() for k, v in result.tree.items()},
        "timings_s": {k: round(v, 4) for k, v in result.timings.items()},
        "convention": "x_reference = T_reference_scan @ [x_scan, 1]; world, row-major, metres",
        "amrst_version": __version__,
    }


def merge_scans(result: MultiScanResult) -> Cloud:
    """All reached scans in the reference frame, one cloud with ``scan_id`` (scan number)."""
    from amrst.results.export import merge_posed

    return merge_posed(result.scans, result.T_reference_scan, result.reference)


def _pair_files(
    out: Path,
    result: MultiScanResult,
    files: Sequence[str],
    truth: Sequence[Transform | None] | None,
    clouds: bool,
    cloud_format: str,
    *,
    more: dict[str, Callable[[Path], object]],
    unchanged: FolderStamp | None,
) -> list[Path]:
    """Write the pair files of ``amrst register`` (built as it builds them) and ``more``."""
    from amrst.results.documents import record_from_registration, result_documents
    from amrst.results.export import export_registration
    from amrst.review.verdict import judge_result

    pair = result.pair
    assert pair is not None
    ref, other = result.reference, 1 - result.reference
    T_truth = None if truth is None else truth[other]
    parts = ["transform", "metrics", "params"] + (
        ["registered", "merged"] if clouds else []
    )
    documents = result_documents(
        record_from_registration(
            pair,
            T_truth,
            target_file=files[ref] if files else result.scans[ref].name,
            source_file=files[other] if files else result.scans[other].name,
            amrst_version=__version__,
            verdict=judge_result(pair, pair.params).as_dict(),
        )
    )
    return export_registration(
        out,
        target=result.scans[ref],
        source=result.scans[other],
        T_target_source=pair.T_target_source,
        params=pair.params,
        cloud_format=cloud_format,
        parts=tuple(parts),
        remove_stale=True,
        documents=documents,
        unchanged=unchanged,
        extra_files=more,
    )


def _many_files(
    out: Path,
    result: MultiScanResult,
    doc: dict[str, Any],
    clouds: bool,
    cloud_format: str,
    *,
    more: dict[str, Callable[[Path], object]],
    unchanged: FolderStamp | None,
) -> list[Path]:
    from amrst import io
    from amrst.files.outdir import replace_files
    from amrst.params import params_to_dict
    from amrst.results.export import CLOUD_NAMES, MANAGED_NAMES, check_output_dir
    from amrst.results.report_html import REPORT_NAME

    n = len(result.scans)
    names = ["transform.json"] + [f"transform_{k}.txt" for k in range(n)]
    names += ["metrics.json", "metrics.csv", "params.json"]
    if clouds:
        names.append(f"merged.{cloud_format}")
    check_output_dir(out, names)
    out.mkdir(parents=True, exist_ok=True)
    transform = {
        "reference": result.reference,
        "status": doc["status"],
        "scans": [
            {
                k: s[k]
                for k in (
                    "index",
                    "name",
                    "file",
                    "reached",
                    "path",
                    "T_reference_scan",
                    "scanner_origin",
                )
            }
            for s in doc["scans"]
        ],
        "convention": doc["convention"],
        "amrst_version": __version__,
    }
    metrics = {k: v for k, v in doc.items() if k not in ("convention",)}
    flat: list[tuple[str, Any]] = []
    _flatten("", metrics, flat)
    buf = _stdio.StringIO()
    writer = csv.writer(buf)
    writer.writerow(["metric", "value"])
    writer.writerows(flat)
    jobs: list[tuple[str, Callable[[Path], object]]] = [
        ("transform.json", lambda p: write_json_atomic(p, transform))
    ]
    for k, T in enumerate(result.T_reference_scan):
        text = "" if T is None else _matrix_text(T)
        jobs.append((f"transform_{k}.txt", text_writer(text)))
    jobs += [
        ("metrics.json", lambda p: write_json_atomic(p, metrics)),
        ("metrics.csv", lambda p: write_text_atomic(p, buf.getvalue())),
        ("params.json", lambda p: write_json_atomic(p, params_to_dict(result.params))),
    ]
    if clouds:
        merged = merge_scans(result)
        jobs.append((f"merged.{cloud_format}", lambda p: io.write(p, merged)))
    jobs += list(more.items())
    # amrst.files.outdir: the whole set replaces the earlier one as one unit.
    managed = {*MANAGED_NAMES, *names, *more}
    # an earlier run's clouds and per-scan files this run does not write (as the pair
    # command removes stale clouds), and its report when this run writes none
    stale = [
        *sorted(
            name
            for name in {*managed, *CLOUD_NAMES}
            if name not in names
            and (name.startswith("transform_") or name in CLOUD_NAMES)
        ),
        *([] if REPORT_NAME in more else [REPORT_NAME]),
    ]
    written, _ = replace_files(
        out, dict(jobs), managed=managed, remove=stale, unchanged=unchanged
    )
    return written


def _matrix_text(T: Transform) -> str:
    return "\n".join(" ".join(f"{v:.12g}" for v in row) for row in T) + "\n"


def _flatten(prefix: str, value: Any, out: list[tuple[str, Any]]) -> None:
    if isinstance(value, dict):
        for k, v in value.items():
            _flatten(f"{prefix}.{k}" if prefix else str(k), v, out)
    elif isinstance(value, list) and value and isinstance(value[0], dict):
        for i, v in enumerate(value):
            _flatten(f"{prefix}.{i}", v, out)
    else:
        out.append((prefix, value))


def export_stamp(out_dir: str | os.PathLike[str], n_scans: int) -> FolderStamp:
    """Stamp what :func:`export_scans` of ``n_scans`` scans may replace in ``out_dir``.

    A run takes it before it registers and hands it to :func:`export_scans`
    (``unchanged``): nothing is written over what another run wrote meanwhile.
    """
    from amrst.files.outdir import folder_stamp
    from amrst.results.export import MANAGED_NAMES
    from amrst.results.report_html import REPORT_NAME

    names = [*MANAGED_NAMES, REPORT_NAME, SUMMARY]
    return folder_stamp(out_dir, names + [f"transform_{k}.txt" for k in range(n_scans)])


def export_scans(
    out_dir: str | os.PathLike[str],
    result: MultiScanResult,
    *,
    files: Sequence[str] = (),
    truth: Sequence[Transform | None] | None = None,
    clouds: bool = False,
    cloud_format: str = "ply",
    unchanged: FolderStamp | None = None,
    report: bool = False,
) -> list[Path]:
    """Write a multi-scan result into ``out_dir``, scans.json and the report with it.

    Parameters
    ----------
    out_dir : path
    result : MultiScanResult
    files : sequence of str
        The scan specs as given, recorded in the files.
    truth : sequence of (4, 4) float64 or None, optional
        True world ``T_reference_scan`` per scan.
    clouds : bool
        Also write the moved/merged clouds.
    cloud_format : {"ply", "las", "laz", "pcd"}
    unchanged : FolderStamp or None
        What ``out_dir`` held when the run began: nothing is written when another run
        changed it since (amrst.files.outdir.folder_stamp).
    report : bool
        Also write report.html: the pair report for two scans, else the multi-scan one.

    Returns
    -------
    list of Path
    """
    from amrst.results.report_html import REPORT_NAME

    out = Path(out_dir)
    doc = summary(result, truth, files)
    more: dict[str, Callable[[Path], object]] = {
        SUMMARY: lambda p: write_json_atomic(p, doc)
    }
    if report:
        more[REPORT_NAME] = text_writer(_report_page(result, files, truth, doc))
    if result.pair is None:
        return _many_files(
            out, result, doc, clouds, cloud_format, more=more, unchanged=unchanged
        )
    return _pair_files(
        out, result, files, truth, clouds, cloud_format, more=more, unchanged=unchanged
    )


def _report_page(
    result: MultiScanResult,
    labels: Sequence[str],
    truth: Sequence[Transform | None] | None,
    doc: dict[str, Any],
) -> str:
    """report.html: the pair report for two scans, else the multi-scan one."""
    from amrst.results.report_html import inputs_from_result, report_page
    from amrst.results.report_multi import multi_report_page

    labels = list(labels) or [scan.name for scan in result.scans]
    if result.pair is not None:
        ref, other = result.reference, 1 - result.reference
        inputs = inputs_from_result(
            result.pair,
            result.scans[ref],
            result.scans[other],
            target_file=labels[ref],
            source_file=labels[other],
            T_truth=None if truth is None else truth[other],
        )
        return report_page(inputs)
    return multi_report_page(result, labels, [s["truth"] for s in doc["scans"]])


def read_scan_truth(
    path: str | os.PathLike[str], n: int, reference: int
) -> list[Transform]:
    """Read the true ``T_reference_scan`` of every scan from a truth file.

    Accepts a multi-scan truth.json (``T_reference_scan``: one 4x4 per scan, onto scan
    0, as ``amrst campaign simulate`` writes; re-expressed onto ``reference``) or, for
    two scans, a pair's (``T_target_source``: the other scan onto the reference, the
    target).

    Raises
    ------
    InvalidInput
        Not a truth document, or it holds a different number of scans.
    """
    from amrst.errors import InvalidInput
    from amrst.io.truth import read_truth_document
    from amrst.types import check_rigid

    doc = read_truth_document(path)
    if "T_reference_scan" in doc:
        mats = [
            check_rigid(T, f"T_reference_scan[{k}] in {path}")
            for k, T in enumerate(doc["T_reference_scan"])
        ]
    elif n == 2:  # a pair's truth: the other scan onto the reference (the target)
        pair = check_rigid(doc["T_target_source"], f"T_target_source in {path}")
        mats = [np.eye(4), np.eye(4)]
        mats[1 - reference] = pair
        return mats
    else:
        mats = [np.eye(4), np.eye(4)]  # a pair's truth: refused below
    if len(mats) != n:
        raise InvalidInput(
            f"{path} gives the truth of {len(mats)} scan(s) but {n} are registered. "
            "Give the truth file of these scans."
        )
    to_ref = invert_transform(mats[reference])
    return [to_ref @ M for M in mats]
