"""The registration case format: a folder with a target scan, a source scan and truth.

The scans are ``target.*`` and ``source.*`` in any format :func:`amrst.io.read` reads
(``amrst simulate`` writes PLY). ``truth.json`` holds ``T_target_source`` (4x4,
row-major nested lists) mapping source coordinates into the target frame; simulated
cases add ``spec_target``, ``spec_source``, ``tree``, ``seed``, ``n_target``,
``n_source`` and ``shared_fraction``.

A plot case holds ``target.ply`` + ``source.ply`` (two scans) or ``scan_1.ply`` ...
``scan_N.ply``: :func:`plot_scan_names` names them, :func:`plot_scan_files` finds them.
"""

from __future__ import annotations

import fnmatch
import os
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from amrst.errors import InvalidInput
from amrst.files.atomic import make_folder, write_json_atomic
from amrst.io.truth import read_truth_document
from amrst.types import Cloud, Transform, check_rigid

if TYPE_CHECKING:
    from collections.abc import Callable

    from amrst.simulate import SimulatedPair

PathLike = str | os.PathLike[str]


@dataclass(frozen=True, eq=False)
class Case:
    """One registration case read from disk.

    Attributes
    ----------
    name : str
        The folder name.
    target, source : Cloud
    T_target_source : (4, 4) float64
        The true transform.
    truth : dict
        Everything in ``truth.json``.
    """

    name: str
    target: Cloud
    source: Cloud
    T_target_source: Transform
    truth: dict[str, Any] = field(default_factory=dict)


def find_cases(cases_dir: PathLike, pattern: str | None = None) -> list[Path]:
    """Case folders under ``cases_dir`` (those holding a truth.json), sorted by name.

    Parameters
    ----------
    cases_dir : path
    pattern : str or None
        Shell pattern on the folder name (``fnmatch``), e.g. ``"*normal*"``.

    Returns
    -------
    list of Path

    Raises
    ------
    InvalidInput
        If ``cases_dir`` is not a folder.
    """
    root = Path(cases_dir)
    if not root.is_dir():
        what = "is not a folder" if root.exists() else "does not exist"
        raise InvalidInput(
            f"{root} {what}: give the folder that holds the case folders (each "
            "with a target.* and a source.* scan and truth.json), or make cases "
            "with 'amrst simulate'."
        )
    found = sorted(p.parent for p in root.glob("*/truth.json"))
    if (root / "truth.json").is_file():
        found.insert(0, root)
    if pattern:
        found = [p for p in found if fnmatch.fnmatch(p.name, pattern)]
    return found


def case_scan(folder: PathLike, role: str) -> Path:
    """Find the case's scan ``role.*`` (target or source) in a format amrst reads.

    Parameters
    ----------
    folder : path
        A case folder.
    role : str
        ``"target"`` or ``"source"``.

    Returns
    -------
    Path
        The one file named ``role`` with an extension :func:`amrst.io.read` knows.

    Raises
    ------
    InvalidInput
        If the folder holds no such file, or more than one.
    """
    from amrst import io

    root = Path(folder)
    exts = io.supported_extensions()
    try:
        found = sorted(
            p for p in root.iterdir() if p.stem == role and p.suffix.lower() in exts
        )
    except OSError as exc:
        raise InvalidInput(f"{root} cannot be listed ({exc.strerror}).") from None
    if not found:
        raise InvalidInput(
            f"{root} has no {role} scan: add {role}.ply (or {role} with another "
            f"extension amrst reads: {' '.join(exts)})."
        )
    if len(found) > 1:
        names = " and ".join(p.name for p in found)
        raise InvalidInput(
            f"{root} holds {names}: keep one {role} scan, so it is clear which one "
            "the truth is for."
        )
    return found[0]


def read_case(path: PathLike) -> Case:
    """Read one case folder.

    Parameters
    ----------
    path : path
        Folder with ``truth.json`` and one ``target.*`` and one ``source.*`` scan
        (see :func:`case_scan`).

    Returns
    -------
    Case

    Raises
    ------
    InvalidInput
        If a file is missing, doubled or unreadable, ``truth.json`` is not a JSON
        object, or its ``T_target_source`` is not a rigid 4x4 transform.
    """
    from amrst import io

    folder = Path(path)
    truth_path = folder / "truth.json"
    if not truth_path.is_file():
        raise InvalidInput(f"{folder} has no truth.json; it is not a case folder.")
    truth = read_truth_document(truth_path)
    T = check_rigid(truth["T_target_source"], f"T_target_source in {truth_path}")
    return Case(
        folder.name,
        io.read(case_scan(folder, "target")),
        io.read(case_scan(folder, "source")),
        T,
        truth,
    )


def truth_dict(
    pair: SimulatedPair, tree_name: str, seed: int | None = None
) -> dict[str, Any]:
    """Return the ``truth.json`` content of a simulated pair (the shared cases' keys).

    Parameters
    ----------
    pair : SimulatedPair
    tree_name : str
        File name of the tree the pair was made from.
    seed : int or None
        The seed given to :func:`amrst.simulate.simulate_pair`.

    Returns
    -------
    dict
    """
    return {
        "T_target_source": np.asarray(pair.T_target_source, dtype=float).tolist(),
        "spec_target": dict(pair.spec_target),
        "spec_source": dict(pair.spec_source),
        "tree": tree_name,
        "seed": seed,
        "n_target": len(pair.target),
        "n_source": len(pair.source),
        "shared_fraction": pair.shared_fraction,
    }


def check_case_folder(out_dir: PathLike) -> Path:
    """Refuse a case folder path that cannot be written or already holds files.

    A simulated case is never written over: a folder that holds files (an earlier
    case, the tree cloud being read) is refused. Nothing is created.

    Parameters
    ----------
    out_dir : path
        A missing or empty folder.

    Returns
    -------
    Path

    Raises
    ------
    InvalidInput
        With what to change.
    """
    from amrst.files.outcheck import check_output_folder  # permissions, loops

    out = check_output_folder(out_dir, "case folder")
    if out.is_dir() and any(out.iterdir()):
        raise InvalidInput(
            f"The case folder {out} already holds files; a simulated case is never "
            "written over: remove it or choose a new folder."
        )
    return out


def write_case(
    pair: SimulatedPair,
    out_dir: PathLike,
    tree_name: str,
    seed: int | None = None,
    extra: dict[str, Any] | None = None,
) -> Path:
    """Write ``target.ply``, ``source.ply`` and ``truth.json`` into ``out_dir``.

    Parameters
    ----------
    pair : SimulatedPair
    out_dir : path
        A new or empty folder (created if missing).
    tree_name : str
        Recorded as ``tree`` in ``truth.json``.
    seed : int or None
        Recorded as ``seed`` in ``truth.json``.
    extra : dict or None
        More ``truth.json`` keys (a field scene's clip radius, neighbours, labels).

    Returns
    -------
    Path
        The case folder.

    Raises
    ------
    InvalidInput
        As :func:`check_case_folder`.
    """
    from amrst.files.outdir import replace_files

    out = make_folder(check_case_folder(out_dir), "case folder")
    truth = {**truth_dict(pair, tree_name, seed), **(extra or {})}
    # The three files as one unit: a kill never pairs new scans with an old truth.
    writers: dict[str, Callable[[Path], object]] = {
        "target.ply": cloud_writer(pair.target),
        "source.ply": cloud_writer(pair.source),
        "truth.json": lambda p: write_json_atomic(p, truth, indent=1),
    }
    replace_files(out, writers, managed=set(writers))
    return out


_PLOT_PAIR = ("target.ply", "source.ply")  # the scans of a plot case of two


def plot_scan_names(n_scans: int) -> list[str]:
    """Return the scan files of a plot case: target + source for two, else scan_k."""
    if n_scans == 2:
        return list(_PLOT_PAIR)
    return [f"scan_{k + 1}.ply" for k in range(n_scans)]


def plot_scan_files(folder: Path) -> list[Path]:
    """Return the scan files of a plot case folder, scan 1 first.

    ``target.ply`` and ``source.ply`` when the folder holds a ``target.ply`` (the
    caller checks that both exist), else every ``scan_<k>.ply`` there, by ``k``.
    """
    if (folder / _PLOT_PAIR[0]).is_file():
        return [folder / name for name in _PLOT_PAIR]
    found = [p for p in folder.glob("scan_*.ply") if re.fullmatch(r"scan_\d+", p.stem)]
    return sorted(found, key=lambda p: int(p.stem.split("_")[1]))


def cloud_writer(cloud: Cloud) -> Callable[[Path], object]:
    """Return a writer of ``cloud`` to the path it is given, for ``replace_files``."""
    from amrst import io

    return lambda path: io.write(path, cloud)
