"""``amrst plot SCAN1 SCAN2 [SCAN ...] --out DIR``: register a plot and inventory it.

The first scan is the reference; ``--pairs I J FILE`` places the link of scans I and J
from point pairs picked by hand (the app's Manual pose dock saves them), ``--leave-out
I J`` leaves a link found wrong out, so the scans are joined through others. Exit 0 when
every scan is registered, or accepted by the technician (a link they accepted in the
app at the pose it has, kept in the folder's review.json), 2 on unusable input, 3
when a scan could not be registered or needs review (the inventory is still written
for the scans that were placed, and the message names the others).
"""

from __future__ import annotations

import sys
from pathlib import Path
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    import argparse

    import numpy as np

EXIT_BAD_INPUT = 2
EXIT_NOT_REGISTERED = 3


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
        "reference's frame, scan_id its number from 1",
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
    p.add_argument("--quiet", action="store_true", help="no progress on stderr")


def run_cli(args: argparse.Namespace) -> int:
    """Register and inventory the plot ``args`` names (see :func:`configure_parser`)."""
    from amrst.errors import AmrstError, InvalidInput
    from amrst.multiscan.cli import read_specs
    from amrst.plot.export import check_out, write_plot
    from amrst.plot.inventory import take_inventory
    from amrst.plot.register import register_plot
    from amrst.plot.review import ACCEPTED, read_review
    from amrst.terminal import TerminalReporter

    out = Path(args.out)
    try:
        check_out(out, args.overwrite)
        by_hand = read_hand_pairs(args.pairs)  # a bad file before minutes of reading
        left_out = [
            scan_numbers(i, j, f"--leave-out {i} {j}") for i, j in args.leave_out
        ]
        # Absolute labels: the app opens the results from anywhere, runs them again.
        clouds, labels = read_specs([str(Path(s).resolve()) for s in args.scans])
        if len(clouds) < 2:
            raise InvalidInput(
                f"{len(clouds)} scan given: a plot needs at least two positions."
            )
        reporter = TerminalReporter(args.quiet)
        reg = register_plot(
            clouds, 0, reporter=reporter, by_hand=by_hand, left_out=left_out
        )
        added = read_review(out, labels).added  # trees the technician added
        inventory = take_inventory(clouds, reg.poses, 0, reporter=reporter, given=added)
        written, states, lost = write_plot(
            out,
            reg,
            inventory,
            labels,
            clouds,
            write_trees=args.write_trees,
            write_cloud=args.write_cloud,
            report=args.report,
            pairs_files={
                scan_numbers(i, j, ""): str(Path(f).resolve()) for i, j, f in args.pairs
            },
        )
    except AmrstError as exc:
        print(f"amrst plot: {exc}", file=sys.stderr)
        return EXIT_BAD_INPUT
    from amrst.review.verdict import FAILED, NEEDS_REVIEW, REGISTERED

    named: dict[str, list[str]] = {
        REGISTERED: [],
        ACCEPTED: [],
        NEEDS_REVIEW: [],
        FAILED: [],
    }
    for label, state in zip(labels, states, strict=True):
        named[state].append(label)
    counts = "".join(
        f", {len(named[s])} {text}"
        for s, text in ((ACCEPTED, "accepted by you"), (NEEDS_REVIEW, "need review"))
        if named[s]
    )
    print(
        f"{out}: {len(inventory.trees)} trees; {len(named[REGISTERED])} of "
        f"{len(clouds)} scans registered{counts}, bundle error "
        f"{100 * reg.bundle_rmse_m:.1f} cm",
        file=sys.stderr,
    )
    print(f"  wrote {_file_list(written)}", file=sys.stderr)
    if lost:
        print(
            f"amrst plot: no tree stands any more where you gave {', '.join(lost)}: "
            "dropped from the review (see review_lost in plot.json).",
            file=sys.stderr,
        )
    if named[NEEDS_REVIEW]:
        print(
            f"amrst plot: needs review: {', '.join(named[NEEDS_REVIEW])}; a link on "
            "the way to the reference is unsure or two links disagree: check the "
            "links in the app's Plot window (Open pair) and Accept a right one; leave "
            "a wrong one out (--leave-out I J) when other links join its scans, or "
            "place it by hand with --pairs I J PAIRS.csv.",
            file=sys.stderr,
        )
    if named[FAILED]:
        print(
            f"amrst plot: not registered (no verified link): "
            f"{', '.join(named[FAILED])}; check those scans overlap the others, or "
            "place each by hand: point pairs with a scan it overlaps, then --pairs I J "
            "PAIRS.csv.",
            file=sys.stderr,
        )
    return EXIT_NOT_REGISTERED if named[NEEDS_REVIEW] or named[FAILED] else 0


def _file_list(written: list[Path]) -> str:
    """Name the files a run wrote; the tree clouds as one entry."""
    top = [p.name for p in written if p.parent.name != "trees"]
    trees = len(written) - len(top)
    return ", ".join(top + ([f"trees/ ({trees} clouds)"] if trees else []))


def read_hand_pairs(
    given: list[list[str]],
) -> dict[tuple[int, int], tuple[np.ndarray, np.ndarray]]:
    """Read ``--pairs I J FILE`` arguments: {(i, j) from 0: (scan i's, scan j's)}.

    Raises
    ------
    InvalidInput
        A scan number that is not a whole number from 1, or an unreadable file.
    """
    from amrst.review.pairs_file import read_pairs

    return {
        scan_numbers(i, j, f"--pairs {i} {j} {path}"): read_pairs(Path(path))
        for i, j, path in given
    }


def scan_numbers(i: str, j: str, given: str) -> tuple[int, int]:
    """Return scans ``i`` and ``j`` (numbered from 1 on the command line) from 0.

    Raises InvalidInput when either is not a whole number from 1.
    """
    from amrst.errors import InvalidInput

    if not (i.isdigit() and j.isdigit() and int(i) >= 1 and int(j) >= 1):
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
