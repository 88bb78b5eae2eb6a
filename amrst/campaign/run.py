"""One tree of a campaign: the task every Dask worker runs, and its resume stamp.

:func:`run_tree` reads the tree's scans, registers them (:func:`amrst.register_scans`),
writes the results into ``results/<id>/`` (the files ``amrst register --report``
writes, plus scans.json) and writes ``stamp.json`` LAST. The stamp holds a hash of everything the
result depends on (the content of every scan and truth file, the scan specs, the
reference, the parameters and the amrst version) and the list of files written; a tree
is done when its stamp matches the current hash and those files exist. A run killed
at any moment therefore leaves either a complete, stamped result or no stamp.

A failure is never raised to the batch: it is written to ``results/<id>/error.json``
and returned as the row's ``error``.
"""

from __future__ import annotations

import contextlib
import datetime as _dt
import hashlib
import json
import os
import time
import traceback
import uuid
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

from amrst import __version__

if TYPE_CHECKING:
    from amrst.campaign.manifest import TreeEntry

STAMP = "stamp.json"
ERROR = "error.json"
#: The Dask worker events a tree sends: {"id": ..., "event": "started" | "finished"}
#: (the app marks a tree running between the two).
TREE_TOPIC = "amrst-tree"
_CHUNK = 1 << 20


def _file_hash(path: Path) -> str:
    h = hashlib.sha256()
    try:
        with open(path, "rb") as f:
            while chunk := f.read(_CHUNK):
                h.update(chunk)
    except OSError as exc:  # missing scans are reported when the tree runs
        return f"unreadable:{exc.__class__.__name__}"
    return h.hexdigest()


def tree_inputs(root: Path, entry: TreeEntry) -> dict[str, Any]:
    """Return the scans a tree's poses are of.

    Their specs, the reference, and a hash of each file's content by its path from
    ``root`` (absolute when outside it).
    """
    files = {name: _file_hash(path) for name, path in _scan_files(root, entry).items()}
    return {"scans": list(entry.scans), "reference": entry.reference, "files": files}


def _scan_files(root: Path, entry: TreeEntry) -> dict[str, Path]:
    """Each scan file of a tree by its path from ``root`` (absolute when outside)."""
    from amrst.io.scans import split_spec

    files: dict[str, Path] = {}
    for spec in entry.scans:
        path, _ = split_spec(root / spec)
        name = path.relative_to(root) if path.is_relative_to(root) else path
        files.setdefault(str(name), path)
    return files


def scan_sizes(root: Path, entry: TreeEntry) -> dict[str, int]:
    """Return the size of each scan file (-1: unreadable).

    Keyed as ``tree_inputs``' files: a test of a replaced scan cheap enough for
    every status shown.
    """
    out: dict[str, int] = {}
    for name, path in _scan_files(root, entry).items():
        try:
            out[name] = path.stat().st_size
        except OSError:
            out[name] = -1
    return out


@dataclass(frozen=True, slots=True)
class TreeStamp:
    """What a tree's result depends on: ``digest`` (hex sha256) and its ``inputs``.

    ``inputs`` is :func:`tree_inputs`, hashed once when the batch plans the tree and
    written as is into ``stamp.json`` (the export checks it against the files).
    """

    digest: str
    inputs: dict[str, Any]
    sizes: dict[str, int] = field(default_factory=dict)  # scan_sizes, not hashed


def tree_stamp(
    root: Path, entry: TreeEntry, params: dict[str, Any], clouds: str = ""
) -> TreeStamp:
    """Return the stamp of everything a tree's result depends on.

    ``clouds``: the cloud format written with the results ("" = none).
    """
    sizes = scan_sizes(root, entry)  # before the hashes: a change while they run shows
    inputs = tree_inputs(root, entry)
    doc = {
        "amrst": __version__,
        **inputs,
        "truth": None if entry.truth is None else _file_hash(root / entry.truth),
        "params": params,
        "clouds": clouds,
    }
    text = json.dumps(doc, sort_keys=True, default=str)
    return TreeStamp(hashlib.sha256(text.encode("utf-8")).hexdigest(), inputs, sizes)


def is_done(out: Path, stamp: str) -> bool:
    """Tell whether ``out`` holds a complete result stamped with ``stamp``."""
    try:
        doc = json.loads((out / STAMP).read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return False
    if not isinstance(doc, dict) or doc.get("stamp") != stamp:
        return False
    return all((out / name).is_file() for name in doc.get("files", []))


def _now() -> str:
    return _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="seconds")


# What a tree task imports on first use (lazily, inside the functions), so that a
# worker's first tree does not pay for it: warm_worker imports them when it starts.
WARM_MODULES = (
    "amrst.files.outdir",
    "amrst.io.scans",
    "amrst.io.truth",
    "amrst.multiscan",
    "amrst.multiscan.cli",
    "amrst.multiscan.export",
    "amrst.multiscan.joint",
    "amrst.neighbours",
    "amrst.pipeline",
    "amrst.results.documents",
    "amrst.results.export",
    "amrst.results.report_html",
    "amrst.results.report_images",
    "amrst.results.report_multi",
    "amrst.review.verdict",
    "amrst.stages.kiss_threads",
    "scipy.linalg",
    "scipy.sparse.csgraph",
    "scipy.spatial",
    "scipy.special",
    "small_gicp",
    "kiss_matcher",
    "matplotlib.backends.backend_agg",
    "matplotlib.figure",
    "matplotlib.patches",
    "threadpoolctl",
)


def warm_worker() -> int:
    """Import what a tree needs, once per worker process; return the process id.

    Optional packages that are not installed are skipped (the tree then falls back
    as it would anyway).
    """
    import importlib

    for name in WARM_MODULES:
        with contextlib.suppress(ImportError):
            importlib.import_module(name)
    return os.getpid()


def run_tree(
    root: str,
    entry: TreeEntry,
    params: dict[str, Any],
    stamp: TreeStamp,
    clouds: str = "",
    threads: int = 2,
) -> dict[str, Any]:
    """Register one tree and write its results; never raises for a bad tree.

    Parameters
    ----------
    root : str
        The campaign folder (absolute: workers on other machines see the same path).
    entry : TreeEntry
    params : dict
        ``params_to_dict`` of the registration parameters.
    stamp : TreeStamp
        :func:`tree_stamp` of this tree, written into ``stamp.json`` when done.
    clouds : str
        Also write the merged cloud (and the moved source of a pair) in this format
        ("ply", "las", "laz", "pcd"); "" writes none, as ``amrst register`` by default.
    threads : int
        Threads for the tree's registration (``register_scans``): 1 when every core
        already runs a task (``amrst.campaign.plan.scan_threads``). The result is the
        same either way.

    Returns
    -------
    dict
        ``id``, ``ok``, ``seconds``, ``status`` (registered, needs review, failed)
        or ``error``, ``worker`` (pid@host).
    """
    from amrst.errors import AmrstError
    from amrst.files.atomic import make_folder, write_json_atomic

    _tell(entry.id, "started")
    base = Path(root)
    out = base / "results" / entry.id
    t0, cpu0 = time.perf_counter(), time.process_time()
    worker = f"{os.getpid()}@{os.uname().nodename}"
    try:
        make_folder(out, "results folder")
        for name in (STAMP, ERROR):
            (out / name).unlink(missing_ok=True)
        status, files = _register(base, entry, params, out, clouds, threads)
    except Exception as exc:  # one tree's failure is data for the table, not a crash
        message = (
            str(exc) if isinstance(exc, AmrstError) else f"{type(exc).__name__}: {exc}"
        )
        doc = {
            "error": message,
            "type": type(exc).__name__,
            "finished_utc": _now(),
            "seconds": time.perf_counter() - t0,
            "worker": worker,
        }
        if not isinstance(exc, AmrstError):
            doc["traceback"] = traceback.format_exc()
        with contextlib.suppress(AmrstError):
            write_json_atomic(out / ERROR, doc)
        _tell(entry.id, "finished")
        return {
            "id": entry.id,
            "ok": False,
            "error": message,
            "seconds": doc["seconds"],
            "worker": worker,
        }
    seconds = time.perf_counter() - t0
    cpu = time.process_time() - cpu0  # every thread of this worker process
    write_json_atomic(
        out / STAMP,
        {
            "stamp": stamp.digest,
            "run": uuid.uuid4().hex,  # this run's result, which a decision names
            "inputs": stamp.inputs,  # what the export checks it still has
            "scan_sizes": stamp.sizes,  # what the status checks
            "files": files,
            "status": status,
            "seconds": seconds,
            "cpu_seconds": cpu,
            "threads": threads,
            "finished_utc": _now(),
            "worker": worker,
        },
    )
    _tell(entry.id, "finished")
    return {
        "id": entry.id,
        "ok": True,
        "status": status,
        "seconds": seconds,
        "cpu_seconds": cpu,
        "worker": worker,
    }


def _tell(tree_id: str, event: str) -> None:
    """Send a worker event: this tree started or finished (nothing outside Dask)."""
    try:
        from distributed import get_worker

        worker = get_worker()
    except (ImportError, ValueError):  # called directly: a test, one tree by hand
        return
    worker.log_event(TREE_TOPIC, {"id": tree_id, "event": event})


def _register(
    base: Path,
    entry: TreeEntry,
    params_doc: dict[str, Any],
    out: Path,
    clouds: str,
    threads: int = 2,
) -> tuple[str, list[str]]:
    from amrst.io.checks import check_scans
    from amrst.io.scans import read_scans
    from amrst.multiscan import register_scans
    from amrst.multiscan.export import export_scans, export_stamp, read_scan_truth
    from amrst.params import params_from_dict

    params = params_from_dict(params_doc)
    before = export_stamp(out, len(entry.scans))
    scans = []
    for spec in entry.scans:
        found = read_scans(base / spec)
        if len(found) != 1:
            raise_many(spec, len(found))
        scans.append(found[0])
    check_scans(scans, list(entry.scans))  # as amrst register checks them
    truth = None
    if entry.truth is not None:
        truth = read_scan_truth(base / entry.truth, len(scans), entry.reference)
    result = register_scans(scans, entry.reference, params, threads=threads)
    written = export_scans(
        out,
        result,
        files=list(entry.scans),
        truth=truth,
        clouds=bool(clouds),
        cloud_format=clouds or "ply",
        report=True,
        unchanged=before,
    )
    return result.status, [p.name for p in written]


def raise_many(spec: str, count: int) -> None:
    """Refuse a manifest scan that names a whole multi-scan file."""
    from amrst.errors import InvalidInput

    raise InvalidInput(
        f"{spec} holds {count} scans; list each one in the manifest as {spec}#0, "
        f"{spec}#1, ..."
    )
