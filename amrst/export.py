"""Export a registration: moved source, merged cloud, transform, metrics, parameters.

Every file is written atomically (temp file, then rename), so a failed export never
leaves half a file or clobbers an earlier one. The parameters go with the results
(KISS-ICP writes its config next to its poses for the same reason).
"""

from __future__ import annotations

import csv
import datetime as _dt
import io as _stdio
from pathlib import Path
from typing import TYPE_CHECKING, Any, cast

import numpy as np

from amrst import io as amrst_io
from amrst.atomic import write_json_atomic, write_text_atomic
from amrst.errors import InvalidInput
from amrst.params_io import params_to_dict
from amrst.pipeline import RegistrationParams
from amrst.types import Cloud, Transform, transform_cloud

if TYPE_CHECKING:
    import os

PARTS = ("registered", "merged", "transform", "metrics", "params")
CLOUD_FORMATS = ("ply", "las", "laz", "pcd")


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

    Returns
    -------
    list of Path
        The files written.

    Raises
    ------
    InvalidInput
        Unknown part or format, or a folder that cannot be written.
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
    out = Path(out_dir)
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise InvalidInput(
            f"Cannot create the export folder {out}: {exc}. Choose another folder."
        ) from exc
    written: list[Path] = []
    if "registered" in parts or "merged" in parts:
        moved = transform_cloud(T_target_source, source, target.offset)
        if "registered" in parts:
            written.append(out / f"registered_source.{cloud_format}")
            amrst_io.write(written[-1], moved)
        if "merged" in parts:
            written.append(out / f"merged.{cloud_format}")
            amrst_io.write(written[-1], merge_clouds(target, moved))
    if "transform" in parts:
        extra = {
            "target": target.name,
            "source": source.name,
            **(transform_extra or {}),
        }
        written.append(out / "transform.json")
        write_json_atomic(
            written[-1], transform_document(T_target_source, T_coarse, **extra)
        )
        written.append(out / "transform.txt")
        write_text_atomic(
            written[-1],
            "\n".join(" ".join(f"{v:.12g}" for v in row) for row in T_target_source)
            + "\n",
        )
    if "metrics" in parts:
        written.append(out / "metrics.json")
        write_json_atomic(written[-1], metrics or {})
        flat: dict[str, Any] = {}
        _flatten("", metrics or {}, flat)
        buf = _stdio.StringIO()
        w = csv.writer(buf)
        w.writerow(["metric", "value"])
        w.writerows(flat.items())
        written.append(out / "metrics.csv")
        write_text_atomic(written[-1], buf.getvalue())
    if "params" in parts:
        written.append(out / "params.json")
        write_json_atomic(written[-1], params_to_dict(params or RegistrationParams()))
    return written
