"""``amrst plot SCAN1 SCAN2 [SCAN ...] --out DIR``: register a plot and inventory it.

The first scan is the reference; ``--pairs I J FILE`` places the link of scans I and J
from point pairs picked by hand (the app's Manual pose dock saves them), ``--leave-out
I J`` leaves a link found wrong out, so the scans are joined through others, and
``--accept I J`` accepts a link that needed review at the folder's last run, at the pose
checked there. Exit 0 when every scan is registered, or accepted by the technician (a
link they accepted, in the app or with ``--accept``, at the pose it has, kept in the
folder's review.json), 2 on unusable input, 3 when a scan could not be registered or
needs review (the inventory is still written for the scans that were placed, and the
message names the others).
"""

from __future__ import annotations

import math
import os
import sys
from pathlib import Path
from typing import TYPE_CHECKING

from amrst.errors import EXIT_INPUT, EXIT_NOT_REGISTERED

if TYPE_CHECKING:
    import argparse
    from collections.abc import Mapping, Sequence

    from amrst.plot.inventory import Tree
    from amrst.plot.run import PlotRun
    from amrst.plot.stand import PlotArea


def configure_parser(p: argparse.ArgumentParser) -> None:
    """Add the ``amrst plot`` arguments to ``p``."""
    p.add_argument(
        "scans",
        nargs="+",
        metavar="SCAN",
        help="the plot's scans (the first is the reference); FILE.e57 gives all its "
        "scans, FILE.e57#k one of them",
    )
    p.add_argument("--out", required=True, metavar="DIR", help="output folder")
    p.add_argument(
        "--write-trees",
        action="store_true",
        help="also write one cloud per tree (trees/T001.ply, ...)",
    )
    p.add_argument(
        "--write-cloud",
        action="store_true",
        help="also write the registered plot, plot.laz: every placed scan in the "
        "reference's frame, scan_id its number from 1, tree its row in trees.csv "
        "(0: no tree)",
    )
    p.add_argument(
        "--report",
        action="store_true",
        help="also write report.html: scans, links, the stem map and the trees",
    )
    p.add_argument(
        "--overwrite",
        action="store_true",
        help="replace the plot another run wrote in --out",
    )
    p.add_argument(
        "--pairs",
        nargs=3,
        action="append",
        default=[],
        metavar=("I", "J", "PAIRS.csv"),
        help="place the link of scans I and J (numbered from 1 in the order given) "
        "from point pairs instead of the automatic match: the CSV of amrst register "
        "--pairs, scan I's points as target_*, scan J's as source_* (repeatable)",
    )
    p.add_argument(
        "--leave-out",
        nargs=2,
        action="append",
        default=[],
        metavar=("I", "J"),
        help="do not register the link of scans I and J (one you found wrong): the "
        "plot joins them through other scans (repeatable)",
    )
    p.add_argument(
        "--accept",
        nargs=2,
        action="append",
        default=[],
        metavar=("I", "J"),
        help="accept the link of scans I and J that needed review at the last run into "
        "--out, at the pose you checked there (report.html, the app's overlay): as "
        "the app's Accept, kept in the folder's review.json, and the scans it places "
        "read accepted (repeatable; with --overwrite)",
    )
    p.add_argument(
        "--plot-radius",
        type=float,
        metavar="R",
        help="the plot's radius (m) for a fixed-radius plot: the report's stand "
        "figures count the trees whose base lies within R of the centre, per hectare",
    )
    p.add_argument(
        "--plot-centre",
        type=float,
        nargs=2,
        metavar=("X", "Y"),
        help="the plot's centre in the reference scan's coordinates, as trees.csv "
        "gives positions (default: where the reference's scanner stood, as an E57 "
        "or PTX file says, else the file's origin)",
    )
    p.add_argument(
        "--scanner",
        nargs=4,
        action="append",
        default=[],
        metavar=("K", "X", "Y", "Z"),
        help="where scan K's scanner stood (numbered from 1), in its file's "
        "coordinates: the tops of a georeferenced scan that does not say are then "
        "checked from there (repeatable)",
    )
    p.add_argument("--quiet", action="store_true", help="no progress on stderr")


def run_cli(args: argparse.Namespace) -> int:
    """Register and inventory the plot ``args`` names (see :func:`configure_parser`)."""
    from amrst.errors import AmrstError, InvalidInput
    from amrst.plot.review import ACCEPTED
    from amrst.plot.run import run_plot
    from amrst.terminal import TerminalReporter

    out = Path(args.out)
    try:
        if not args.out.strip():
            raise InvalidInput("--out is empty: name the results folder.")
        pairs = hand_pairs(args.pairs)
        left_out = [
            scan_numbers(i, j, f"--leave-out {i} {j}") for i, j in args.leave_out
        ]
        accept = [scan_numbers(i, j, f"--accept {i} {j}") for i, j in args.accept]
        scanners = given_scanners(args.scanner)
        # Absolute labels (a symlink keeps its own name): the app opens the results
        # from anywhere and runs them again.
        run = run_plot(
            [os.path.abspath(s) for s in args.scans],
            out,
            overwrite=args.overwrite,
            pairs=pairs,
            left_out=left_out,
            accept=accept,
            scanners=scanners,
            write_trees=args.write_trees,
            write_cloud=args.write_cloud,
            report=args.report,
            plot_radius_m=args.plot_radius,
            plot_centre=None if args.plot_centre is None else tuple(args.plot_centre),
            reporter=TerminalReporter(args.quiet),
        )
    except AmrstError as exc:
        print(f"amrst plot: {exc}", file=sys.stderr)
        return EXIT_INPUT
    from amrst.plot.stand import counted
    from amrst.review.verdict import FAILED, NEEDS_REVIEW, REGISTERED

    named: dict[str, list[str]] = {
        REGISTERED: [],
        ACCEPTED: [],
        NEEDS_REVIEW: [],
        FAILED: [],
    }
    for label, state in zip(run.labels, run.states, strict=True):
        named[state].append(label)
    counts = "".join(
        f", {len(named[s])} {text}"
        for s, text in ((ACCEPTED, "accepted by you"), (NEEDS_REVIEW, "need review"))
        if named[s]
    )
    bundle = run.registration.bundle_rmse_m
    print(
        f"{out}: {counted(len(run.inventory.trees), 'tree')}; {len(named[REGISTERED])} of "
        f"{len(run.labels)} scans registered{counts}"
        + (f", bundle error {100 * bundle:.1f} cm" if math.isfinite(bundle) else ""),
        file=sys.stderr,
    )
    if run.inventory.trees:
        print(f"  {_flags_line(run.inventory.trees)}", file=sys.stderr)
    print(f"  wrote {_file_list(list(run.written))}", file=sys.stderr)
    if run.area is not None:
        _say_stand(out, run.area)
    for note in run.notes:
        print(f"amrst plot: {note}.", file=sys.stderr)
    if why := run.inventory.why_none:
        print(f"amrst plot: no tree listed: {why}.", file=sys.stderr)
    if run.lost:
        print(
            f"amrst plot: no tree stands any more where you gave "
            f"{', '.join(run.lost)}: "
            "dropped from the review (see review_lost in plot.json).",
            file=sys.stderr,
        )
    _say_what_to_check(run, named, left_out)
    return EXIT_NOT_REGISTERED if named[NEEDS_REVIEW] or named[FAILED] else 0


def _say_what_to_check(
    run: PlotRun,
    named: Mapping[str, list[str]],
    left_out: Sequence[tuple[int, int]],
) -> None:
    """Say which scans need review or failed, and what the technician's pairs showed."""
    from amrst.plot.inventory import seen_from_any
    from amrst.plot.register import HAND_ORIGIN
    from amrst.plot.review import unsure_scans
    from amrst.plot.stand import counted
    from amrst.review.verdict import FAILED, NEEDS_REVIEW, REGISTERED

    if named[NEEDS_REVIEW]:
        unsure = unsure_scans(run.states)
        resting = seen_from_any(run.inventory.trees, unsure)
        print(
            f"amrst plot: needs review: {', '.join(named[NEEDS_REVIEW])} "
            f"({counted(resting, 'tree')} seen from {'it' if len(unsure) == 1 else 'them'}, "
            "trees.csv scans_to_check); a link on "
            "the way to the reference is unsure or two links disagree: check the "
            "links in the app's Plot window (Open pair) and Accept a right one (or "
            "check it in --report's report.html and run again with --overwrite "
            "--accept I J); leave "
            "a wrong one out (--leave-out I J) when other links join its scans, or "
            "place it by hand with --pairs I J PAIRS.csv.",
            file=sys.stderr,
        )
    for pl in run.registration.links:  # what the technician's own pairs showed
        ln = pl.link
        if ln.origin == HAND_ORIGIN and ln.status != REGISTERED:
            print(
                f"amrst plot: link {ln.target + 1}-{ln.source + 1}, from your point "
                f"pairs, {ln.status}: {ln.message}",
                file=sys.stderr,
            )
    if named[FAILED]:
        from amrst.plot.register import cut_off

        stems = [len(s.stems.stems) for s in run.registration.scans]
        turned = run.registration.turned
        cut = cut_off(len(run.labels), 0, left_out)
        failed = [
            f"{label} ({counted(n, 'stem')} found"
            + ("; the links left out cut it off" if k in cut else "")
            + (f"; it seems to stand {turned[k]}: export it z up" if turned[k] else "")
            + ")"
            for k, (label, state, n) in enumerate(
                zip(run.labels, run.states, stems, strict=True)
            )
            if state == FAILED
        ]
        # The scans are placed onto the first: without stems it holds none of them.
        bare = (
            f"the reference, {run.labels[0]}, shows no stem: give first a scan that "
            "shows the plot's stems, z up; else "
            if stems[0] == 0
            else ""
        )
        print(
            f"amrst plot: not registered (no verified link): {', '.join(failed)}; "
            f"{bare}check those scans overlap the others and show their stems, z up, "
            "or place each by hand: point pairs with a scan it overlaps, then --pairs "
            "I J PAIRS.csv.",
            file=sys.stderr,
        )


def _say_stand(out: Path, area: PlotArea) -> None:
    """Sum up the stand inside the plot from the trees.csv just written.

    Says so when the plot leaves out every tree listed (a centre or radius mistaken).
    """
    from amrst.plot.export import read_tree_rows
    from amrst.plot.stand import stand, stand_line

    st = stand(read_tree_rows(out), area)
    print(f"  stand {stand_line(st, area)}", file=sys.stderr)
    if st.outside and not st.trees:
        cx, cy = area.centre_xy
        print(
            f"amrst plot: no listed tree stands within {area.radius_m:g} m of "
            f"({cx:.2f}, {cy:.2f}): check --plot-centre and --plot-radius against "
            "trees.csv's x_m, y_m.",
            file=sys.stderr,
        )


def _flags_line(trees: Sequence[Tree]) -> str:
    """Count the trees by DBH quality and by height flag, for a first look."""
    from collections import Counter

    def tally(values: Counter[str], first: str) -> str:
        order = [first, *sorted(k for k in values if k != first)]
        return ", ".join(f"{values[k]} {k}" for k in order if values[k])

    dbh = Counter(t.stem.dbh_quality for t in trees)
    height = Counter(t.stem.height_flag for t in trees)
    return f"DBH: {tally(dbh, 'ok')}; height: {tally(height, 'ok')}"


def _file_list(written: list[Path]) -> str:
    """Name the files a run wrote; the tree clouds as one entry."""
    top = [p.name for p in written if p.parent.name != "trees"]
    trees = len(written) - len(top)
    return ", ".join(top + ([f"trees/ ({trees} clouds)"] if trees else []))


def hand_pairs(given: list[list[str]]) -> dict[tuple[int, int], str]:
    """Return ``--pairs I J FILE`` arguments as {(i, j) from 0: FILE}.

    Raises
    ------
    InvalidInput
        A scan number that is not a whole number from 1, or a link given twice.
    """
    from amrst.errors import InvalidInput

    pairs: dict[tuple[int, int], str] = {}
    for i, j, path in given:
        link = scan_numbers(i, j, f"--pairs {i} {j} {path}")
        if link in pairs or link[::-1] in pairs:
            raise InvalidInput(
                f"--pairs {i} {j} is given twice: give one pairs file per link."
            )
        pairs[link] = path
    return pairs


def given_scanners(given: list[list[str]]) -> dict[int, tuple[float, float, float]]:
    """Return ``--scanner K X Y Z`` arguments as {scan from 0: (x, y, z)}.

    Raises
    ------
    InvalidInput
        A scan number that is not a whole number from 1, a coordinate that is no
        finite number, or a scan given twice.
    """
    from amrst.errors import InvalidInput
    from amrst.types import MAX_COORD_M

    scanners: dict[int, tuple[float, float, float]] = {}
    for k, *xyz in given:
        what = f"The scanner of scan {k} at {' '.join(v[:20] for v in xyz)}"
        if not (k.isdecimal() and int(k) >= 1):
            raise InvalidInput(f"{what}: name the scan by its number from 1, e.g. 2.")
        try:
            x, y, z = (float(v) for v in xyz)
        except ValueError:
            raise InvalidInput(f"{what}: give X Y Z as numbers (metres).") from None
        if not all(abs(v) <= MAX_COORD_M for v in (x, y, z)):  # NaN too
            raise InvalidInput(
                f"{what}: give X Y Z as numbers within {MAX_COORD_M:g} m (metres)."
            )
        if int(k) - 1 in scanners:
            raise InvalidInput(f"The scanner of scan {k} is given twice: give one.")
        scanners[int(k) - 1] = (x, y, z)
    return scanners


def scan_numbers(i: str, j: str, given: str) -> tuple[int, int]:
    """Return scans ``i`` and ``j`` (numbered from 1 on the command line) from 0.

    Raises InvalidInput when either is not a whole number from 1.
    """
    from amrst.errors import InvalidInput

    # isdecimal, not isdigit: "²" is a digit int() refuses.
    if not (i.isdecimal() and j.isdecimal() and int(i) >= 1 and int(j) >= 1):
        raise InvalidInput(
            f"{given}: name the two scans by their numbers from 1 in the order given, "
            "e.g. 1 3."
        )
    return int(i) - 1, int(j) - 1


def main(argv: list[str] | None = None) -> int:
    """Run ``amrst plot`` on its own (``python -m amrst.plot.cli``)."""
    import argparse

    parser = argparse.ArgumentParser(prog="amrst plot", description=__doc__)
    configure_parser(parser)
    return run_cli(parser.parse_args(argv))


if __name__ == "__main__":
    sys.exit(main())
