"""Export a registration: moved source, merged cloud, transform, metrics, parameters.

Every file is first written into a hidden staging folder inside the export folder; only
when all of them are written are they renamed into place. A failed export therefore
never leaves half a file, a partial set of new files, or a clobbered earlier one. The
parameters go with the results (KISS-ICP writes its config next to its poses for the
same reason).
"""

from __future__ import annotations

import contextlib
import csv
import datetime as _dt
import io as _stdio
import logging
import os
import shutil
import tempfile
from pathlib import Path
from typing import TYPE_CHECKING, Any, cast

import numpy as np

from amrst import io as amrst_io
from amrst.atomic import write_json_atomic, write_text_atomic
from amrst.errors import AmrstError, InvalidInput
from amrst.params import RegistrationParams, params_to_dict
from amrst.types import Cloud, Transform, transform_cloud

if TYPE_CHECKING:
    from collections.abc import Callable, Iterable

logger = logging.getLogger(__name__)

PARTS = ("registered", "merged", "transform", "metrics", "params")
CLOUD_FORMATS = ("ply", "las", "laz", "pcd")
# The cloud files an export may write; a run that writes none of one name removes an
# earlier run's copy with ``remove_stale`` (so no cloud of another result is left).
CLOUD_NAMES = tuple(
    f"{stem}.{fmt}" for stem in ("registered_source", "merged") for fmt in CLOUD_FORMATS
)
_STAGING_PREFIX = ".amrst-export-"


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

    The folder may be missing: it is created to try writing in it, then removed again
    (with any parents created for it), so nothing is left behind.

    Parameters
    ----------
    out_dir : path
        The export folder.
    names : iterable of str
        File names to be written there; none of them may be a folder.

    Returns
    -------
    Path
        ``out_dir`` as a Path.

    Raises
    ------
    InvalidInput
        An empty path, an existing file, a folder that cannot be created or written,
        or a file name taken by a folder.
    """
    if not os.fspath(out_dir).strip():
        raise InvalidInput(
            "The export folder path is empty; give a folder name (it is created when "
            "missing)."
        )
    out = Path(out_dir)
    if out.exists() and not out.is_dir():
        raise InvalidInput(
            f"The export folder {out} is an existing file; choose a folder (it is "
            "created when missing)."
        )
    missing = []
    parent = out
    while not parent.exists() and parent != parent.parent:
        missing.append(parent)
        parent = parent.parent
    if parent.exists() and not parent.is_dir():
        raise InvalidInput(
            f"Cannot create the export folder {out}: {parent} is a file, not a folder. "
            "Choose another folder."
        )
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        _remove_empty(missing)
        raise InvalidInput(
            f"Cannot create the export folder {out}: {exc.strerror or exc}. Choose "
            "another folder."
        ) from exc
    try:
        fd, probe = tempfile.mkstemp(prefix=".amrst-probe-", dir=out)
        os.close(fd)
        os.unlink(probe)
    except OSError as exc:
        raise InvalidInput(
            f"Cannot write in the export folder {out}: {exc.strerror or exc}. Check "
            "its permissions or choose another folder."
        ) from exc
    finally:
        _remove_empty(missing)
    for name in names:
        if (out / name).is_dir():
            raise InvalidInput(
                f"Cannot write {out / name}: a folder has that name. Remove or rename "
                "it, or choose another export folder."
            )
    return out


def _remove_empty(folders: list[Path]) -> None:
    """Remove the folders ``check_output_dir`` created (deepest first), if empty."""
    for folder in folders:
        with contextlib.suppress(OSError):
            folder.rmdir()


def remove_stale_clouds(
    out_dir: str | os.PathLike[str], keep: Iterable[str]
) -> list[Path]:
    """Remove the export cloud files of an earlier run that this run did not write.

    Only the exact names in ``CLOUD_NAMES`` are touched (``registered_source.<fmt>``,
    ``merged.<fmt>``), and only regular files or links.

    Parameters
    ----------
    out_dir : path
    keep : iterable of str
        The names this run wrote.

    Returns
    -------
    list of Path
        The files removed.
    """
    out, kept = Path(out_dir), set(keep)
    removed = []
    for name in CLOUD_NAMES:
        path = out / name
        if name not in kept and (path.is_file() or path.is_symlink()):
            try:
                path.unlink()
            except OSError as exc:
                logger.warning("Could not remove the earlier %s: %s", path, exc)
                continue
            removed.append(path)
    return removed


def merge_clouds(target: Cloud, moved_source: Cloud) -> Cloud:
    """Both scans in one cloud with a ``scan_id`` field (0 = target, 1 = source).

    Attributes present in only one scan are kept, with zeros for the other scan's points.
    Both clouds must share an offset (``transform_cloud`` with the target offset does that).
    """
    names = list(dict.fromkeys([*target.attributes, *moved_source.attributes]))
    attrs: dict[str, np.ndarray] = {}
    for name in names:
        a, b = target.attributes.get(name), moved_source.attributes.get(name)
        ref = cast("np.ndarray", a if a is not None else b)  # one of them is set
        dtype = np.result_type(*(x.dtype for x in (a, b) if x is not None))
        parts = [
            np.asarray(x, dtype)
            if x is not None
            else np.zeros((len(c), *ref.shape[1:]), dtype)
            for x, c in ((a, target), (b, moved_source))
        ]
        attrs[name] = np.concatenate(parts)
    attrs["scan_id"] = np.r_[
        np.zeros(len(target), np.uint8), np.ones(len(moved_source), np.uint8)
    ]
    return Cloud(
        np.vstack([target.xyz, moved_source.xyz]),
        target.offset,
        attrs,
        "merged",
        target.meta,
    )


def _flatten(prefix: str, value: Any, out: dict[str, Any]) -> None:
    if isinstance(value, dict):
        for k, v in value.items():
            _flatten(f"{prefix}.{k}" if prefix else str(k), v, out)
    else:
        out[prefix] = value


def transform_document(
    T_target_source: Transform, T_coarse: Transform | None, **extra: Any
) -> dict[str, Any]:
    """Return the transform.json content: 4x4 row-major nested lists plus context."""
    doc: dict[str, Any] = {
        "T_target_source": np.asarray(T_target_source, float).tolist()
    }
    if T_coarse is not None:
        doc["T_coarse"] = np.asarray(T_coarse, float).tolist()
    doc["convention"] = "x_target = T_target_source @ [x_source, 1]; row-major, metres"
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
        Once the new files are in place, remove the ``CLOUD_NAMES`` files this call
        did not write (an earlier run's clouds), logging one warning line.

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
    out = check_output_dir(out_dir, names)
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
                p, merge_clouds(target, moved)
            )
    if "transform" in parts:
        extra = {
            "target": target.name,
            "source": source.name,
            **(transform_extra or {}),
        }
        doc = transform_document(T_target_source, T_coarse, **extra)
        text = (
            "\n".join(" ".join(f"{v:.12g}" for v in row) for row in T_target_source)
            + "\n"
        )
        writers["transform.json"] = lambda p: write_json_atomic(p, doc)
        writers["transform.txt"] = lambda p: write_text_atomic(p, text)
    if "metrics" in parts:
        flat: dict[str, Any] = {}
        _flatten("", metrics or {}, flat)
        buf = _stdio.StringIO()
        w = csv.writer(buf)
        w.writerow(["metric", "value"])
        w.writerows(flat.items())
        writers["metrics.json"] = lambda p: write_json_atomic(p, metrics or {})
        writers["metrics.csv"] = lambda p: write_text_atomic(p, buf.getvalue())
    if "params" in parts:
        pdoc = params_to_dict(params or RegistrationParams())
        writers["params.json"] = lambda p: write_json_atomic(p, pdoc)
    written = _write_all(out, [(name, writers[name]) for name in names])
    if remove_stale:
        removed = remove_stale_clouds(out, names)
        if removed:
            logger.warning(
                "Removed %d cloud file(s) of an earlier run from %s that this run did "
                "not write: %s.",
                len(removed),
                out,
                ", ".join(p.name for p in removed),
            )
    return written


def _write_all(
    out: Path, jobs: list[tuple[str, Callable[[Path], object]]]
) -> list[Path]:
    """Write every file into a staging folder in ``out``, then rename them all in.

    A failure while writing leaves ``out`` as it was; a failure while renaming (rare:
    same folder) removes the files of this run already renamed.
    """
    try:
        stage = Path(tempfile.mkdtemp(prefix=_STAGING_PREFIX, dir=out))
    except OSError as exc:
        raise InvalidInput(
            f"Cannot write in the export folder {out}: {exc.strerror or exc}. Check "
            "its permissions or choose another folder."
        ) from exc
    placed: list[Path] = []
    try:
        for name, write in jobs:
            try:
                write(stage / name)
            except AmrstError as exc:
                # Name the real destination, not the staging folder.
                raise type(exc)(str(exc).replace(str(stage), str(out))) from exc
        for name, _ in jobs:
            final, new = out / name, stage / name
            if final.is_file():  # keep the permissions of the file it replaces
                os.chmod(new, final.stat().st_mode & 0o777)
            os.replace(new, final)
            placed.append(final)
    except BaseException as exc:
        for path in placed:
            with contextlib.suppress(OSError):
                path.unlink()
        if isinstance(exc, AmrstError) or not isinstance(exc, Exception):
            raise
        raise AmrstError(
            f"Could not write the export into {out}: {exc} ({type(exc).__name__}). "
            "No new file was left there; check the free disk space and the "
            "permissions, then retry."
        ) from exc
    finally:
        shutil.rmtree(stage, ignore_errors=True)
    return placed
