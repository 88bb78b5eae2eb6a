"""Several virtual tripod scans of one tree, with exact poses (multi-scan test cases).

The scanner of :mod:`amrst.simulate` placed ``n`` times around the trunk: consecutive
positions ``separation_deg`` apart (drawn in a range, e.g. 60-120 deg, so some pairs
stand nearly opposite). The folder written holds ``scan_0.ply`` ... (each in its own
scanner frame) and ``truth.json`` with every scanner pose ``T_tree_scanner`` and
``T_reference_scan`` (scan k's frame -> scan 0's frame).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from amrst.errors import InvalidInput
from amrst.simulate.settings import Bounds, check_numbers, check_range
from amrst.types import Cloud, Transform, invert_transform

if TYPE_CHECKING:
    import argparse
    import os
    from collections.abc import Callable, Sequence


@dataclass(frozen=True, eq=False)
class SimulatedScans:
    """``scans[k]`` in scanner k's frame; ``poses[k]`` = ``T_tree_scanner`` of scan k."""

    scans: tuple[Cloud, ...]
    poses: tuple[Transform, ...]
    specs: tuple[dict[str, float], ...]

    def T_reference_scan(self, reference: int = 0) -> list[Transform]:
        """Return the true transforms scan k -> the reference scan, for every k."""
        inv = invert_transform(self.poses[reference])
        return [inv @ pose for pose in self.poses]


#: The azimuth step between consecutive positions (deg).
STEP_DEG = Bounds(0.0, 360.0, above_low=True, unit="degrees")


def check_scan_settings(
    *,
    n_scans: Any,
    seed: Any,
    separation_deg: Sequence[float],
    distance_m: float,
    res_deg: float,
    noise_m: float,
    tilt_deg: float = 0.5,
    height_m: float = 1.5,
    cli: bool = False,
) -> None:
    """Refuse settings :func:`simulate_scans` cannot use, naming the setting.

    Parameters
    ----------
    n_scans, seed, separation_deg, distance_m, res_deg, noise_m, tilt_deg, height_m
        As :func:`simulate_scans`; the ranges are those of
        :data:`amrst.simulate.settings.SETTINGS` and :data:`STEP_DEG`.
    cli : bool
        Name the settings as ``amrst campaign simulate`` options (``--scans``).

    Raises
    ------
    InvalidInput
        The first setting that is wrong, and what it must be.
    """
    numbers = {
        "scans" if cli else "n_scans": n_scans,
        "seed": seed,
        "distance_m": distance_m,
        "res_deg": res_deg,
        "noise_m": noise_m,
        "tilt_deg": tilt_deg,
        "height_m": height_m,
    }
    check_numbers(numbers, cli=cli)
    check_range("separation_deg", separation_deg, cli=cli, bounds=STEP_DEG)


def simulate_scans(
    tree: Cloud,
    n_scans: int = 4,
    *,
    seed: int = 0,
    separation_deg: tuple[float, float] = (60.0, 120.0),
    distance_m: float = 8.0,
    res_deg: float = 0.04,
    noise_m: float = 0.004,
    tilt_deg: float = 0.5,
    height_m: float = 1.5,
) -> SimulatedScans:
    """Scan ``tree`` from ``n_scans`` positions around its trunk.

    Parameters
    ----------
    tree : Cloud
        A complete tree cloud (z up).
    n_scans : int
        2 to 50.
    seed : int
        Seeds the positions, headings, tilts and noise.
    separation_deg : (float, float)
        Range of the azimuth step between consecutive positions (deg; 0 < low <=
        high <= 360).
    distance_m, res_deg, noise_m, tilt_deg, height_m : float
        As :func:`amrst.simulate.simulate_pair`.

    Returns
    -------
    SimulatedScans

    Raises
    ------
    InvalidInput
        A setting out of range (see :func:`check_scan_settings`), or a scan that
        keeps under 100 points.
    """
    from amrst.simulate import (
        MIN_POINTS,
        footprints,
        scanner_pose,
        simulate_scan,
        trunk_base,
    )

    check_scan_settings(
        n_scans=n_scans,
        seed=seed,
        separation_deg=separation_deg,
        distance_m=distance_m,
        res_deg=res_deg,
        noise_m=noise_m,
        tilt_deg=tilt_deg,
        height_m=height_m,
    )
    lo, hi = separation_deg[0], separation_deg[-1]  # one value: a fixed step
    rng = np.random.default_rng(seed)
    base = trunk_base(tree.xyz)
    radius = footprints(tree.xyz)
    azimuth = float(rng.uniform(-180.0, 180.0))
    scans, poses, specs = [], [], []
    for k in range(n_scans):
        if k:
            azimuth += float(rng.uniform(lo, hi))
        spec = {
            "azimuth_deg": (azimuth + 180.0) % 360.0 - 180.0,
            "distance_m": float(distance_m),
            "height_m": float(height_m),
            "res_deg": float(res_deg),
            "noise_m": float(noise_m),
            "heading_deg": float(rng.uniform(0.0, 360.0)),
            "tilt_deg": float(rng.uniform(0.0, tilt_deg)),
            "tilt_dir_deg": float(rng.uniform(0.0, 360.0)),
        }
        pose = scanner_pose(base, spec)
        scan, _ = simulate_scan(
            tree, pose, res_deg=res_deg, noise_m=noise_m, footprint_m=radius, rng=rng
        )
        if len(scan) < MIN_POINTS:
            raise InvalidInput(
                f"Simulated scan {k} of {tree.name or 'the tree'} keeps only "
                f"{len(scan)} point(s); use a denser tree or a smaller res_deg."
            )
        scans.append(Cloud(scan.xyz, scan.offset, scan.attributes, f"scan_{k}"))
        poses.append(pose)
        specs.append(spec)
    return SimulatedScans(tuple(scans), tuple(poses), tuple(specs))


def write_scans(
    sim: SimulatedScans,
    out_dir: str | os.PathLike[str],
    tree_name: str = "",
    seed: int | None = None,
) -> Path:
    """Write ``scan_<k>.ply`` and ``truth.json`` into a new or empty folder, as one unit.

    Returns
    -------
    Path
        The folder.

    Raises
    ------
    InvalidInput
        As :func:`amrst.io.cases.check_case_folder` (a folder that holds files is
        never written over).
    """
    from amrst.files.atomic import make_folder, write_json_atomic
    from amrst.files.outdir import replace_files
    from amrst.io.cases import check_case_folder, cloud_writer

    out = make_folder(check_case_folder(out_dir), "case folder")
    names = [f"scan_{k}.ply" for k in range(len(sim.scans))]
    onto_first = sim.T_reference_scan(0)
    doc: dict[str, Any] = {
        # scan_1 onto scan_0, so the folder is also a pair case for amrst register
        "T_target_source": onto_first[1].tolist(),
        "T_reference_scan": [T.tolist() for T in onto_first],
        "T_tree_scanner": [T.tolist() for T in sim.poses],
        "specs": list(sim.specs),
        "scans": names,
        "reference": 0,
        "tree": tree_name,
        "seed": seed,
        "convention": "x_reference = T_reference_scan[k] @ [x_scan_k, 1]; row-major, metres",
    }
    # The scans and the truth as one unit: a kill never pairs them with older ones.
    writers: dict[str, Callable[[Path], object]] = {
        name: cloud_writer(scan) for name, scan in zip(names, sim.scans, strict=True)
    }
    writers["truth.json"] = lambda p: write_json_atomic(p, doc)
    replace_files(out, writers, managed=set(writers))
    return out


def configure_parser(p: argparse.ArgumentParser) -> None:
    """Add the ``amrst campaign simulate`` arguments to ``p``."""
    p.add_argument("tree", metavar="TREE", help="complete tree cloud")
    p.add_argument(
        "--out", required=True, metavar="DIR", help="new or empty folder to write"
    )
    p.add_argument("--scans", type=int, default=4, help="scanner positions (default 4)")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument(
        "--separation-deg",
        type=float,
        nargs=2,
        default=[60.0, 120.0],
        metavar=("LOW", "HIGH"),
        help="range of the azimuth step between positions (default 60 120)",
    )
    p.add_argument("--distance-m", type=float, default=8.0)
    p.add_argument("--res-deg", type=float, default=0.04)
    p.add_argument("--noise-m", type=float, default=0.004)


def run_cli(args: argparse.Namespace) -> int:
    """Simulate the scans and write the folder; return the exit status."""
    import sys

    from amrst import io
    from amrst.io.cases import check_case_folder
    from amrst.simulate.settings import one_tree

    # The settings and the output folder are checked before the (slow) simulation.
    check_scan_settings(
        n_scans=args.scans,
        seed=args.seed,
        separation_deg=args.separation_deg,
        distance_m=args.distance_m,
        res_deg=args.res_deg,
        noise_m=args.noise_m,
        cli=True,
    )
    check_case_folder(args.out)
    tree = one_tree(io.read(args.tree), args.tree)
    sim = simulate_scans(
        tree,
        args.scans,
        seed=args.seed,
        separation_deg=(args.separation_deg[0], args.separation_deg[1]),
        distance_m=args.distance_m,
        res_deg=args.res_deg,
        noise_m=args.noise_m,
    )
    out = write_scans(sim, args.out, Path(args.tree).name, args.seed)
    sizes = ", ".join(str(len(s)) for s in sim.scans)
    print(f"{out}: {len(sim.scans)} scans ({sizes} points)", file=sys.stderr)
    return 0
