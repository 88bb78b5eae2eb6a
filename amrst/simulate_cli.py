"""``amrst simulate``: argument parsing and the command (plain and field-like scenes)."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

from amrst.simulate import check_case_folder, check_settings, simulate_pair, write_case

if TYPE_CHECKING:
    import argparse


def configure_parser(p: argparse.ArgumentParser) -> None:
    """Add the ``amrst simulate`` arguments to ``p``.

    Parameters
    ----------
    p : argparse.ArgumentParser
    """
    p.add_argument(
        "tree", metavar="TREE", help="complete tree cloud (any readable format)"
    )
    p.add_argument("--out", required=True, metavar="DIR", help="case folder to write")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--separation-deg", type=float, default=90.0)
    p.add_argument(
        "--distance-m",
        type=float,
        nargs="+",
        default=[8.0],
        metavar="D",
        help="trunk-to-scanner distance; give two values for target and source",
    )
    p.add_argument("--res-deg", type=float, default=0.04)
    p.add_argument("--noise-m", type=float, default=0.004)
    p.add_argument("--tilt-deg", type=float, default=0.5)


def run_cli(args: argparse.Namespace) -> int:
    """Simulate a pair from ``args`` (see :func:`configure_parser`) and write the case.

    Parameters
    ----------
    args : argparse.Namespace

    Returns
    -------
    int
        Exit status: 0 on success, 2 when the input cannot be used.
    """
    import sys

    from amrst import io
    from amrst.errors import AmrstError

    distance = (
        args.distance_m[0] if len(args.distance_m) == 1 else tuple(args.distance_m)
    )
    try:
        # Settings and the output folder are checked before the (slow) simulation.
        check_settings(
            seed=args.seed,
            separation_deg=args.separation_deg,
            distance_m=tuple(args.distance_m),
            res_deg=args.res_deg,
            noise_m=args.noise_m,
            tilt_deg=args.tilt_deg,
            cli=True,
        )
        check_case_folder(args.out)
        tree = io.read(args.tree)
        pair = simulate_pair(
            tree,
            seed=args.seed,
            separation_deg=args.separation_deg,
            distance_m=distance,
            res_deg=args.res_deg,
            noise_m=args.noise_m,
            tilt_deg=args.tilt_deg,
        )
        out = write_case(pair, args.out, Path(args.tree).name, args.seed)
    except AmrstError as exc:
        print(f"amrst simulate: {exc}", file=sys.stderr)
        return 2
    print(
        f"{out}: target {len(pair.target)} points, source {len(pair.source)} points, "
        f"shared {pair.shared_fraction:.0%}",
        file=sys.stderr,
    )
    return 0
