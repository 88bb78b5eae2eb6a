"""``amrst simulate``: argument parsing and the command (one tree, or a forest plot)."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path
from typing import TYPE_CHECKING, Any

from amrst.errors import InvalidInput
from amrst.simulate import check_case_folder, check_settings, simulate_pair, write_case
from amrst.simulate.settings import check_numbers, check_range, one_tree

if TYPE_CHECKING:
    import argparse

_KINDS = ("normal", "hard", "sparse", "wind")  # amrst.simulate.plot.KINDS
#: The ground's largest slope when --slope-deg is not given (as FieldOptions').
SLOPE_DEG = 8.0


def configure_parser(p: argparse.ArgumentParser) -> None:
    """Add the ``amrst simulate`` arguments to ``p``.

    Parameters
    ----------
    p : argparse.ArgumentParser
    """
    p.description = (
        "Make virtual tripod scans with exact truth: two scans of one tree (plain or "
        "field-like), or with --plot a forest plot of several trees scanned from "
        "several positions."
    )
    p.add_argument(
        "tree_files",
        nargs="+",
        metavar="TREE",
        help="complete tree cloud (any readable format); with --plot, the trees to "
        "stand on the plot",
    )
    p.add_argument(
        "--out", required=True, metavar="DIR", help="new or empty case folder to write"
    )
    p.add_argument("--seed", type=int, default=0)
    p.add_argument(
        "--separation-deg", type=float, default=None, help="one tree: default 90"
    )
    p.add_argument(
        "--distance-m",
        type=float,
        nargs="+",
        default=None,
        metavar="D",
        help="trunk-to-scanner distance; give two values for target and source "
        "(default 8)",
    )
    p.add_argument("--res-deg", type=float, default=0.04)
    p.add_argument("--noise-m", type=float, default=0.004)
    p.add_argument(
        "--tilt-deg",
        type=float,
        default=None,
        help="largest residual tilt of a scanner (default 0.5; with --plot, the "
        "kind's)",
    )
    field = p.add_argument_group(
        "field scene",
        "make a field-like case: the tree on a rough ground disc, with neighbours and "
        "shrubs, both scans cut with a cylinder around the stem (any of these options "
        "turns it on)",
    )
    field.add_argument(
        "--ground", action="store_true", help="add a rough, sloped ground disc"
    )
    field.add_argument(
        "--slope-deg",
        type=float,
        help=f"largest slope of the ground (default {SLOPE_DEG:g}); adds the ground",
    )
    field.add_argument(
        "--neighbours",
        nargs="+",
        default=[],
        metavar="TREE",
        help="other tree clouds to stand 2.5-6 m away (a file may be given twice)",
    )
    field.add_argument(
        "--shrubs",
        type=int,
        default=None,
        metavar="N",
        help="number of shrubs (on a plot: default 15)",
    )
    field.add_argument(
        "--clip-radius-m",
        type=float,
        default=None,
        metavar="R",
        help="cut both scans with a vertical cylinder of this radius around the stem",
    )
    _configure_plot(p)


def _configure_plot(p: argparse.ArgumentParser) -> None:
    plot = p.add_argument_group(
        "forest plot",
        "--plot stands the TREEs on a plot (random heading, scale 0.85-1.15, feet at "
        "least 3 m apart within 10 m of the centre) on a rough ground with shrubs "
        "(--slope-deg, --shrubs), and scans it from tripod positions inside the plot; "
        "each scan keeps --range-m. Writes target.ply + source.ply (2 positions) or "
        "scan_1.ply ... scan_N.ply, and truth.json: every scan's pose in scan 1's "
        "frame and every tree's stem, DBH and height",
    )
    plot.add_argument(
        "--plot", action="store_true", help="make a forest plot case of the TREEs"
    )
    plot.add_argument(
        "--positions", type=int, default=None, metavar="N", help="default 2"
    )
    plot.add_argument(
        "--kind",
        choices=_KINDS,
        default=None,
        help="normal (default): positions 6-12 m apart, tilt up to 0.3 deg; hard: "
        "12-16 m, up to 2 deg; sparse: the scans after the first at twice --res-deg; "
        "wind: every crown swayed 8-15 cm at the top in the scans after the first",
    )
    plot.add_argument(
        "--spacing-m",
        type=float,
        nargs="+",
        default=None,
        metavar="M",
        help="distance from each position to the one before: one value or LOW HIGH "
        "(default: the kind's)",
    )
    plot.add_argument(
        "--relief-m",
        type=float,
        default=None,
        metavar="M",
        help="hills and hollows 5-15 m across of about M m on the ground, so that it "
        "bends away from any plane (default 0: a plane with small bumps)",
    )
    plot.add_argument(
        "--range-m",
        type=float,
        default=None,
        metavar="R",
        help="each scan keeps what lies within R m of the scanner (default 22)",
    )
    plot.add_argument(
        "--trees",
        dest="n_trees",
        type=int,
        default=None,
        metavar="N",
        help="place N of the TREEs, drawn by the seed (default: all of them)",
    )


def run_cli(args: argparse.Namespace) -> int:
    """Simulate a case from ``args`` (see :func:`configure_parser`) and write it.

    Parameters
    ----------
    args : argparse.Namespace

    Returns
    -------
    int
        Exit status: 0 on success, 2 when the input cannot be used.
    """
    import sys

    from amrst.errors import AmrstError

    try:
        message = _run_plot(args) if args.plot else _run_pair(args)
    except AmrstError as exc:
        print(f"amrst simulate: {exc}", file=sys.stderr)
        return 2
    print(message, file=sys.stderr)
    return 0


def _check_common(args: argparse.Namespace, tilt_deg: float) -> None:
    """Refuse bad numbers before the (slow) simulation, naming the option."""
    check_settings(
        seed=args.seed,
        separation_deg=90.0 if args.separation_deg is None else args.separation_deg,
        distance_m=tuple(args.distance_m or [8.0]),
        res_deg=args.res_deg,
        noise_m=args.noise_m,
        tilt_deg=tilt_deg,
        cli=True,
    )
    check_numbers(
        {
            "slope_deg": args.slope_deg,
            "shrubs": args.shrubs,
            "clip_radius_m": args.clip_radius_m,
            "positions": args.positions,
            "range_m": args.range_m,
            "relief_m": args.relief_m,
            "trees": args.n_trees,
        },
        cli=True,
        optional=True,  # options not given
    )
    if args.spacing_m is not None:
        check_range("spacing_m", args.spacing_m, cli=True)


def _refuse(args: argparse.Namespace, names: dict[str, str], what: str) -> None:
    for dest, flag in names.items():
        if getattr(args, dest) not in (None, False, []):
            raise InvalidInput(f"{flag} {what}.")


def _run_pair(args: argparse.Namespace) -> str:
    """Simulate two scans of one tree (plain or field-like); return the summary."""
    from amrst import io

    _refuse(
        args,
        {
            "positions": "--positions",
            "kind": "--kind",
            "spacing_m": "--spacing-m",
            "range_m": "--range-m",
            "relief_m": "--relief-m",
            "n_trees": "--trees",
        },
        "applies to a forest plot: add --plot",
    )
    if len(args.tree_files) != 1:
        raise InvalidInput(
            f"Give one TREE for a two-scan case (got {len(args.tree_files)}), or "
            "add --plot to stand several on a forest plot."
        )
    tree_file = args.tree_files[0]
    distances = args.distance_m or [8.0]
    distance = distances[0] if len(distances) == 1 else tuple(distances)
    scan: dict[str, Any] = {
        "separation_deg": 90.0 if args.separation_deg is None else args.separation_deg,
        "distance_m": distance,
        "res_deg": args.res_deg,
        "noise_m": args.noise_m,
        "tilt_deg": 0.5 if args.tilt_deg is None else args.tilt_deg,
    }
    # Settings and the output folder are checked before the (slow) simulation.
    _check_common(args, scan["tilt_deg"])
    check_case_folder(args.out)
    tree = one_tree(io.read(tree_file), tree_file)
    field = _field_options(args, io)
    if field is None:
        pair = simulate_pair(tree, seed=args.seed, **scan)
        out = write_case(pair, args.out, Path(tree_file).name, args.seed)
    else:
        from amrst.simulate.field import simulate_field_pair

        pair, info = simulate_field_pair(tree, field, seed=args.seed, **scan)
        out = write_case(pair, args.out, Path(tree_file).name, args.seed, info)
    return (
        f"{out}: target {len(pair.target)} points, source {len(pair.source)} points, "
        f"shared {pair.shared_fraction:.0%}"
    )


def _field_options(args: argparse.Namespace, io: Any) -> Any:
    """Return the FieldOptions the arguments ask for, or None for a plain case."""
    ground = args.ground or args.slope_deg is not None
    if not (
        ground
        or args.neighbours
        or args.shrubs is not None
        or args.clip_radius_m is not None
    ):
        return None
    from amrst.simulate.field import FieldOptions

    return FieldOptions(
        ground=ground,
        slope_deg=SLOPE_DEG if args.slope_deg is None else args.slope_deg,
        neighbours=tuple(one_tree(io.read(path), path) for path in args.neighbours),
        shrubs=args.shrubs or 0,
        clip_radius_m=args.clip_radius_m,
    )


def _run_plot(args: argparse.Namespace) -> str:
    """Simulate a forest plot scanned from several positions; return the summary."""
    from amrst import io
    from amrst.simulate.plot import (
        plot_options,
        simulate_plot,
        write_plot_case,
    )
    from amrst.terminal import TerminalReporter

    _refuse(
        args,
        {
            "separation_deg": "--separation-deg",
            "distance_m": "--distance-m",
            "ground": "--ground",
            "neighbours": "--neighbours",
            "clip_radius_m": "--clip-radius-m",
        },
        "applies to a one-tree case, not to --plot (a plot has its ground and its trees; "
        "--spacing-m sets how far apart its positions stand)",
    )
    _check_common(args, 0.0 if args.tilt_deg is None else args.tilt_deg)
    changes: dict[str, Any] = {
        "res_deg": args.res_deg,
        "noise_m": args.noise_m,
        "slope_deg": SLOPE_DEG if args.slope_deg is None else args.slope_deg,
    }
    for dest in ("positions", "tilt_deg", "shrubs", "range_m", "relief_m"):
        if getattr(args, dest) is not None:
            changes[dest] = getattr(args, dest)
    if args.n_trees is not None:
        changes["trees"] = args.n_trees
    if args.spacing_m is not None:
        changes["spacing_m"] = (args.spacing_m[0], args.spacing_m[-1])
    options = plot_options(args.kind or "normal", **changes)
    check_case_folder(args.out)
    trees = [
        replace(one_tree(io.read(path), path), name=_tree_name(path))
        for path in args.tree_files
    ]
    plot = simulate_plot(trees, options, seed=args.seed, reporter=TerminalReporter())
    out = write_plot_case(plot, args.out, args.seed)
    sizes = ", ".join(str(len(s)) for s in plot.scans)
    return (
        f"{out}: {len(plot.scans)} scans ({sizes} points) of a {options.kind} plot "
        f"of {len(plot.trees)} trees"
    )


def _tree_name(path: str) -> str:
    """Name a tree in the truth by its folder and file (``voxr/Tree_t0.asc``)."""
    p = Path(path).resolve()
    return f"{p.parent.name}/{p.name}"
