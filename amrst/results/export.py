"""Export a registration: moved source, merged cloud, transform, metrics, parameters.

Every file is first written into a staging folder; the whole set then replaces the old
one in one atomic step (amrst.files.outdir), under the folder's lock (amrst.files.folderlock). A
failed or killed export therefore never leaves half a file, a mix of old and new files,
or a clobbered earlier one. The parameters go with the results (KISS-ICP writes its
config next to its poses for the same reason).
"""

from __future__ import annotations

import datetime as _dt
import json
import logging
import os
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from amrst import io as amrst_io
from amrst.errors import InvalidInput
from amrst.files.atomic import write_json_atomic, write_text_atomic
from amrst.files.folderlock import DEFAULT_TIMEOUT_S
from amrst.files.outcheck import check_output_folder, same_file
from amrst.files.outdir import FolderStamp, clear_dead_run, replace_files
from amrst.params import RegistrationParams, params_to_dict
from amrst.results.documents import CONVENTION, metrics_csv
from amrst.results.report_html import REPORT_NAME
from amrst.types import Cloud, Transform, transform_cloud

if TYPE_CHECKING:
    from collections.abc import Callable, Iterable, Mapping, Sequence

    from amrst.results.documents import ResultDocuments

logger = logging.getLogger(__name__)

PARTS = ("registered", "merged", "transform", "metrics", "params")
CLOUD_FORMATS = ("ply", "las", "laz", "pcd")
# The cloud files an export may write; with ``remove_stale`` a run removes the earlier
# run's files it does not write (so no file of another result is left).
CLOUD_NAMES = tuple(
    f"{stem}.{fmt}" for stem in ("registered_source", "merged") for fmt in CLOUD_FORMATS
)
# Every name an export may write: a folder holding only these (and our hidden files)
# is swapped as a whole (amrst.files.outdir).
MANAGED_NAMES = frozenset(
    [
        *CLOUD_NAMES,
        "transform.json",
        "transform.txt",
        "metrics.json",
        "metrics.csv",
        "params.json",
    ]
)


def output_names(parts: Iterable[str] = PARTS, cloud_format: str = "ply") -> list[str]:
    """File names :func:`export_registration` writes for ``parts``, in order.

    Parameters
    ----------
    parts : iterable of str
        Any of ``PARTS``.
    cloud_format : str
        One of ``CLOUD_FORMATS``.

    Returns
    -------
    list of str
    """
    chosen = set(parts)
    names = []
    if "registered" in chosen:
        names.append(f"registered_source.{cloud_format}")
    if "merged" in chosen:
        names.append(f"merged.{cloud_format}")
    if "transform" in chosen:
        names += ["transform.json", "transform.txt"]
    if "metrics" in chosen:
        names += ["metrics.json", "metrics.csv"]
    if "params" in chosen:
        names.append("params.json")
    return names


def check_output_dir(
    out_dir: str | os.PathLike[str], names: Iterable[str] = ()
) -> Path:
    """Check, before any long work, that ``out_dir`` can take the export files.

    See :func:`amrst.files.outcheck.check_output_folder` (nothing is left behind).
    What a killed run left in the folder (its lock, temporary files) is cleared
    first (:func:`amrst.files.outdir.clear_dead_run`).

    Raises
    ------
    InvalidInput
        With what to change.
    """
    out = check_output_folder(out_dir, "export folder", names)
    clear_dead_run(out)
    return out


def previous_files(out_dir: str | os.PathLike[str]) -> list[str] | None:
    """Return the scan files of the export in ``out_dir`` (target first), if any.

    Read from its ``transform.json`` (a pair's or several scans'); None when the
    folder holds no readable one.
    """
    path = Path(out_dir) / "transform.json"
    try:
        doc = json.loads(path.read_text(encoding="utf-8"))
        if "scans" in doc:
            return [str(scan["file"]) for scan in doc["scans"]]
        return [str(doc["target_file"]), str(doc["source_file"])]
    except (OSError, ValueError, KeyError, TypeError):
        return None


def refuse_inputs_in_out(
    out_dir: str | os.PathLike[str],
    files: Sequence[str],
    written: Callable[[str], bool] = lambda name: name in (*MANAGED_NAMES, REPORT_NAME),
) -> None:
    """Refuse a scan file that lies in ``out_dir`` under a name the run may write.

    ``written`` tells those names (default: a pair's export and its report). A
    ``#k`` after a file name is ignored; a link is followed to the file it names.

    Raises
    ------
    InvalidInput
        Naming the file, whatever ``--overwrite`` says: the run would replace or
        remove a scan it reads.
    """
    folder = os.path.realpath(out_dir)  # realpath: a link loop is no error here
    for spec in files:
        head, sep, tail = spec.rpartition("#")
        # The file itself, wherever a link to it lies.
        real = os.path.realpath(
            head if sep and tail.replace(",", "").isdigit() else spec
        )
        if os.path.dirname(real) == folder and written(os.path.basename(real)):
            raise InvalidInput(
                f"{spec} is a file the run writes in {out_dir}: copy it elsewhere, "
                "or give another --out folder."
            )


def refuse_other_export(
    out_dir: str | os.PathLike[str], files: Sequence[str], *, overwrite: bool = False
) -> None:
    """Refuse to replace what another run wrote in ``out_dir``, unless asked to.

    Running the same scans again replaces their own export; a folder that holds the
    export of other files, a plot's results, or files an export writes whose owner
    is unknown is kept as it is.

    Raises
    ------
    InvalidInput
        When ``out_dir`` holds such files and ``overwrite`` is False.
    """
    what = other_export(out_dir, files)
    if overwrite or what is None:
        return
    raise InvalidInput(
        f"{out_dir} holds {what}: choose another --out folder, or add --overwrite to "
        "replace it."
    )


def other_export(out_dir: str | os.PathLike[str], files: Sequence[str]) -> str | None:
    """Say what ``out_dir`` holds that an export of ``files`` would replace, or None.

    None for a folder without such files, or with the export of the same scan files
    (target first). Otherwise "the export of SOURCE onto TARGET" (or "of N scans
    onto TARGET"), "a forest plot's results (plot.json)", or the export's file names
    found without the transform.json that says whose they are.
    """
    folder = Path(out_dir)
    before = previous_files(folder)
    if before is not None:
        if len(before) == len(files) and all(
            same_file(a, b) for a, b in zip(before, files, strict=True)
        ):
            return None
        onto = Path(before[0]).name
        if len(before) == 2:
            return f"the export of {Path(before[1]).name} onto {onto}"
        return f"the export of {len(before)} scans onto {onto}"
    if (folder / "plot.json").exists():
        return "a forest plot's results (plot.json)"
    found = sorted(
        n for n in (*MANAGED_NAMES, REPORT_NAME) if os.path.lexists(folder / n)
    )
    return f"{', '.join(found)} of another run" if found else None


def merge_moved(ref: Cloud, moved: Sequence[tuple[int, Cloud]]) -> Cloud:
    """Return scans already moved into ``ref``'s frame as one cloud, ``scan_id`` = k.

    Attributes present in some scans only are kept, with zeros for the others' points.

    Raises InvalidInput when no scan is given (none placed).
    """
    if not moved:
        raise InvalidInput("No scan is placed: there is nothing to merge.")
    names = list(dict.fromkeys(a for _, c in moved for a in c.attributes))
    attrs: dict[str, np.ndarray] = {}
    for name in names:
        cols = [c.attributes.get(name) for _, c in moved]
        given = [a for a in cols if a is not None]
        dtype = np.result_type(*(a.dtype for a in given))
        attrs[name] = np.concatenate(
            [
                np.asarray(a, dtype)
                if a is not None
                else np.zeros((len(c), *given[0].shape[1:]), dtype)
                for a, (_, c) in zip(cols, moved, strict=True)
            ]
        )
    attrs["scan_id"] = np.concatenate([np.full(len(c), k, np.uint16) for k, c in moved])
    xyz = np.vstack([c.xyz for _, c in moved])
    return Cloud(xyz, ref.offset, attrs, "merged", ref.meta)


def merge_posed(
    clouds: Sequence[Cloud], poses: Sequence[Transform | None], reference: int
) -> Cloud:
    """Every posed scan moved into the reference's frame, as one cloud (``merge_moved``).

    ``poses[k]`` takes scan k's world coordinates into the reference's; None: not
    placed, left out.
    """
    ref = clouds[reference]
    moved = [
        (k, transform_cloud(T, clouds[k], ref.offset))
        for k, T in enumerate(poses)
        if T is not None
    ]
    return merge_moved(ref, moved)


def transform_document(
    T_target_source: Transform, T_coarse: Transform | None, **extra: Any
) -> dict[str, Any]:
    """Return the transform.json content: 4x4 row-major nested lists plus context."""
    doc: dict[str, Any] = {
        "T_target_source": np.asarray(T_target_source, float).tolist()
    }
    if T_coarse is not None:
        doc["T_coarse"] = np.asarray(T_coarse, float).tolist()
    doc["convention"] = CONVENTION
    doc["created"] = _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="seconds")
    doc.update(extra)
    return doc


def export_registration(
    out_dir: str | os.PathLike[str],
    *,
    target: Cloud,
    source: Cloud,
    T_target_source: Transform,
    T_coarse: Transform | None = None,
    metrics: dict[str, Any] | None = None,
    params: RegistrationParams | None = None,
    cloud_format: str = "ply",
    parts: tuple[str, ...] = PARTS,
    transform_extra: dict[str, Any] | None = None,
    remove_stale: bool = False,
    lock_timeout_s: float = DEFAULT_TIMEOUT_S,
    documents: ResultDocuments | None = None,
    unchanged: FolderStamp | None = None,
    extra_files: Mapping[str, Callable[[Path], object]] | None = None,
) -> list[Path]:
    """Write the chosen parts of a registration into ``out_dir``.

    Parameters
    ----------
    out_dir : path
        Created when missing.
    target, source : Cloud
        The scans as read (full resolution, all attributes).
    T_target_source : (4, 4) float64
        World-frame transform from source to target.
    T_coarse : (4, 4) float64 or None
    metrics : dict or None
        Nested dict of numbers (coarse/fine metrics, timings, truth errors).
    params : RegistrationParams or None
    cloud_format : {"ply", "las", "laz", "pcd"}
    parts : tuple of str
        Any of "registered", "merged", "transform", "metrics", "params".
    transform_extra : dict or None
        More fields for transform.json (confidence, timings, file names).
    remove_stale : bool
        Drop from the folder the ``MANAGED_NAMES`` files this call does not write (an
        earlier run's clouds, transform, metrics, parameters) and an earlier
        ``report.html`` this call does not write, in the same atomic step, logging one
        warning line.
    lock_timeout_s : float
        How long to wait for another writer of ``out_dir`` (amrst.files.folderlock).
    documents : ResultDocuments or None
        The result files from :func:`amrst.results.documents.result_documents`; when given,
        ``metrics``, ``T_coarse`` and ``transform_extra`` are not used.
    unchanged : FolderStamp or None
        What ``out_dir`` held when the run began: nothing is written when another run
        changed it since (amrst.files.outdir.folder_stamp).
    extra_files : dict of str to callable, optional
        More files of the result: name -> ``write(path)`` (``report.html``, a
        multi-scan ``scans.json``), written in the same atomic step.

    Returns
    -------
    list of Path
        The files written.

    Raises
    ------
    InvalidInput
        Unknown part or format, or a folder that cannot be written.
    AmrstError
        A file could not be written; no new file of this call is left in ``out_dir``.
    FolderBusy
        Another run kept writing ``out_dir`` for ``lock_timeout_s``.

    Notes
    -----
    The folder's files are replaced as one unit (see amrst.files.outdir for what a kill at
    each instant leaves); earlier files this call does not write are kept.
    """
    unknown = set(parts) - set(PARTS)
    if unknown:
        raise InvalidInput(
            f"Unknown export part(s) {sorted(unknown)}; choose from {PARTS}."
        )
    if cloud_format not in CLOUD_FORMATS:
        raise InvalidInput(
            f"Unknown cloud format {cloud_format!r}; choose from {CLOUD_FORMATS}."
        )
    names = output_names(parts, cloud_format)
    more = dict(extra_files or {})
    out = check_output_dir(out_dir, [*names, *more])
    out.mkdir(parents=True, exist_ok=True)  # checked above: it can be created
    writers: dict[str, Callable[[Path], object]] = {}
    if "registered" in parts or "merged" in parts:
        moved = transform_cloud(T_target_source, source, target.offset)
        if "registered" in parts:
            writers[f"registered_source.{cloud_format}"] = lambda p: amrst_io.write(
                p, moved
            )
        if "merged" in parts:
            writers[f"merged.{cloud_format}"] = lambda p: amrst_io.write(
                p, merge_moved(target, [(0, target), (1, moved)])
            )
    if documents is not None:  # the one result layout (amrst.results.documents)
        doc, mdoc = documents.transform, documents.metrics
        text, table = documents.transform_txt, documents.metrics_csv
    else:
        names_doc = {
            "target": target.name,
            "source": source.name,
            **(transform_extra or {}),
        }
        doc = transform_document(T_target_source, T_coarse, **names_doc)
        text = (
            "\n".join(" ".join(f"{v:.12g}" for v in row) for row in T_target_source)
            + "\n"
        )
        mdoc, table = metrics or {}, metrics_csv(metrics or {})
    if "transform" in parts:
        writers["transform.json"] = lambda p: write_json_atomic(p, doc)
        writers["transform.txt"] = lambda p: write_text_atomic(p, text)
    if "metrics" in parts:
        writers["metrics.json"] = lambda p: write_json_atomic(p, mdoc)
        writers["metrics.csv"] = lambda p: write_text_atomic(p, table)
    if "params" in parts:
        pdoc = params_to_dict(params or RegistrationParams())
        writers["params.json"] = lambda p: write_json_atomic(p, pdoc)
    writers.update(more)
    # What this call does not write, an earlier report too, describes another result.
    stale = [*sorted(MANAGED_NAMES.difference(names)), REPORT_NAME]
    stale = [n for n in stale if n not in more] if remove_stale else []
    written, removed = replace_files(
        out,
        {name: writers[name] for name in [*names, *more]},
        managed=MANAGED_NAMES.union(more),
        remove=stale,
        lock_timeout_s=lock_timeout_s,
        unchanged=unchanged,
    )
    if removed:
        logger.warning(
            "Removed %d file(s) an earlier run wrote in %s (this run leaves them out "
            "or writes them anew): %s.",
            len(removed),
            out,
            ", ".join(removed),
        )
    return written
