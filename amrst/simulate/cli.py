"""``amrst simulate``: argument parsing and the command (plain and field-like scenes)."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Any

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
    field = p.add_argument_group(
        "field scene",
        "make a field-like case: the tree on a rough ground disc, with neighbours and "
        "shrubs, both scans cut with a cylinder around the stem (any of these options "
        "turns it on)",
    )
    field.add_argument(
        "--ground", action="store_true", help="add a rough, sloped ground disc"
    )
    field.add_argument("--slope-deg", type=float, default=8.0, help="largest slope")
    field.add_argument(
        "--neighbours",
        nargs="+",
        default=[],
        metavar="TREE",
        help="other tree clouds to stand 2.5-6 m away (a file may be given twice)",
    )
    field.add_argument("--shrubs", type=int, default=None, metavar="N")
    field.add_argument(
        "--clip-radius-m",
        type=float,
        default=None,
        metavar="R",
        help="cut both scans with a vertical cylinder of this radius around the stem",
    )


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
        field = _field_options(args, io)
        if field is None:
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
        else:
            from amrst.simulate.field import simulate_field_pair

            pair, info = simulate_field_pair(
                tree,
                field,
                seed=args.seed,
                separation_deg=args.separation_deg,
                distance_m=distance,
                res_deg=args.res_deg,
                noise_m=args.noise_m,
                tilt_deg=args.tilt_deg,
            )
            out = write_case(pair, args.out, Path(args.tree).name, args.seed, info)
    except AmrstError as exc:
        print(f"amrst simulate: {exc}", file=sys.stderr)
        return 2
    print(
        f"{out}: target {len(pair.target)} points, source {len(pair.source)} points, "
        f"shared {pair.shared_fraction:.0%}",
        file=sys.stderr,
    )
    return 0


def _field_options(args: argparse.Namespace, io: Any) -> Any:
    """Return the FieldOptions the arguments ask for, or None for a plain case."""
    if not (
        args.ground
        or args.neighbours
        or args.shrubs is not None
        or args.clip_radius_m is not None
    ):
        return None
    from amrst.simulate.field import FieldOptions

    return FieldOptions(
        ground=args.ground,
        slope_deg=args.slope_deg,
        neighbours=tuple(io.read(path) for path in args.neighbours),
        shrubs=args.shrubs or 0,
        clip_radius_m=args.clip_radius_m,
    )
