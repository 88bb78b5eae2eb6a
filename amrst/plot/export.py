"""What ``amrst plot`` hands over: the inventory, the links, the poses, the tree clouds.

Every file of a run is written into the output folder as one unit
(``files.outdir.replace_files``). A folder holding another run's ``plot.json`` is
refused unless the caller says to overwrite it.
"""

from __future__ import annotations

import csv
import io as _stdio
from typing import TYPE_CHECKING, Any

from amrst.errors import InvalidInput
from amrst.plot.inventory import TREE_COLUMNS

if TYPE_CHECKING:
    from collections.abc import Callable, Sequence
    from pathlib import Path

    import numpy as np

    from amrst.plot.inventory import Inventory
    from amrst.plot.register import PlotRegistration
    from amrst.types import Cloud

PLOT_JSON = "plot.json"
TREES_CSV = "trees.csv"
TREES_XLSX = "trees.xlsx"
TREES_DIR = "trees"


def check_out(out: Path, overwrite: bool) -> None:
    """Refuse a folder that holds another run's output, unless ``overwrite``."""
    if (out / PLOT_JSON).exists() and not overwrite:
        raise InvalidInput(
            f"{out} already holds a plot ({PLOT_JSON}): give another --out folder, or "
            "--overwrite to replace it."
        )


def trees_csv(inventory: Inventory) -> str:
    """Return trees.csv: one row per tree, the columns of ``TREE_COLUMNS``."""
    buf = _stdio.StringIO()
    writer = csv.DictWriter(buf, fieldnames=TREE_COLUMNS, lineterminator="\n")
    writer.writeheader()
    writer.writerows(t.row() for t in inventory.trees)
    return buf.getvalue()


def plot_document(
    reg: PlotRegistration, inventory: Inventory, labels: Sequence[str]
) -> dict[str, Any]:
    """Return plot.json's content: scans and poses, links, bundle, tree count."""
    links = []
    for pl in reg.links:
        entry = pl.link.as_dict()
        entry["stems_shared"] = len(pl.shared)
        entry["loop_confirmed"] = reg.loop_confirms(pl.link)
        links.append(entry)
    return {
        "reference": labels[reg.reference],
        "scans": [
            {
                "label": label,
                "status": status,
                "reached": pose is not None,
                "T_reference_scan": None if pose is None else pose.tolist(),
                "path": None if path is None else [k + 1 for k in path],
                "stems": len(scan.stems.stems),
            }
            for label, pose, path, scan, status in zip(
                labels, reg.poses, reg.paths, reg.scans, reg.statuses, strict=True
            )
        ],
        "links": links,
        "bundle_rmse_m": reg.bundle_rmse_m,
        "joint": None if reg.joint is None else reg.joint.as_dict(),
        "loops": reg.loops,
        "trees": len(inventory.trees),
        "timings_s": {k: round(v, 3) for k, v in reg.timings.items()},
    }


def write_plot(
    out: Path,
    reg: PlotRegistration,
    inventory: Inventory,
    labels: Sequence[str],
    reference: Cloud,
    *,
    write_trees: bool = False,
) -> list[Path]:
    """Write the run's files into ``out`` as one unit; return the files written."""
    from amrst.files.atomic import strict_json
    from amrst.files.outdir import replace_files

    doc, _ = strict_json(plot_document(reg, inventory, labels))
    writers: dict[str, Callable[[Path], object]] = {
        PLOT_JSON: lambda p: p.write_text(_json_text(doc)),
        TREES_CSV: lambda p: p.write_text(trees_csv(inventory)),
    }
    xlsx = _xlsx_writer(inventory)
    if xlsx is not None:
        writers[TREES_XLSX] = xlsx
    if write_trees:
        for k, tree in enumerate(inventory.trees):
            writers[f"{TREES_DIR}/{tree.tree_id}.ply"] = _tree_writer(
                inventory.tree_points(k), reference
            )
    managed = {PLOT_JSON, TREES_CSV, TREES_XLSX, TREES_DIR}
    written, _ = replace_files(out, writers, managed=managed)
    return written


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


def _xlsx_writer(inventory: Inventory) -> Callable[[Path], object] | None:
    """trees.xlsx when openpyxl is installed."""
    from amrst.files.atomic import xlsx_book

    book = xlsx_book("trees", TREE_COLUMNS, (t.row() for t in inventory.trees))
    return None if book is None else book.save
