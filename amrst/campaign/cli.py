"""``amrst campaign init|status|decide|export|simulate`` and ``amrst batch``.

amrst.cli adds these with a few lines: ``configure_campaign`` / ``run_campaign`` for
``amrst campaign``, ``configure_batch`` / ``run_batch_cli`` for ``amrst batch``.
"""

from __future__ import annotations

import sys
import time
from typing import TYPE_CHECKING, Any

from amrst.errors import EXIT_NOT_REGISTERED

if TYPE_CHECKING:
    import argparse

    from amrst.campaign.manifest import Campaign


class TerminalBar:
    """Trees done, failed, running and the time left, on stderr."""

    def __init__(self, quiet: bool = False) -> None:
        self._tty = sys.stderr.isatty()
        self._quiet = quiet
        self._t0 = time.perf_counter()

    def check_cancelled(self) -> None:
        """Never cancels: Ctrl+C interrupts the command itself."""

    def update(
        self,
        done: int,
        errors: int,
        running: int,
        total: int,
        left_s: float | None,
        row: dict[str, Any] | None,
    ) -> None:
        """Redraw the bar (terminal) or write one line per finished tree."""
        if self._quiet:
            return
        left = "" if left_s is None else f", {_clock(left_s)} left"
        text = (
            f"{done}/{total} trees done, {errors} with an error, {running} running"
            f"{left}"
        )
        if self._tty:
            share = (done + errors) / total if total else 1.0
            bar = "#" * int(30 * share)
            sys.stderr.write(f"\r[{bar:<30}] {text:<70}")
            if done + errors >= total:
                sys.stderr.write("\n")
        elif row is not None:
            what = (
                row.get("status")
                if row.get("ok")
                else f"failed with an error: {row.get('error', '')}"
            )
            sys.stderr.write(
                f"{time.perf_counter() - self._t0:7.1f}s {row['id']}: {what} ({text})\n"
            )
        sys.stderr.flush()


def _clock(seconds: float) -> str:
    s = round(seconds)
    return (
        f"{s // 3600}:{s // 60 % 60:02d}:{s % 60:02d}"
        if s >= 3600
        else f"{s // 60}:{s % 60:02d}"
    )


def configure_campaign(p: argparse.ArgumentParser) -> None:
    """Add ``init``, ``status``, ``decide``, ``export``, ``simulate`` under ``amrst campaign``."""
    from amrst.multiscan import simulate

    sub = p.add_subparsers(dest="campaign_command", metavar="ACTION", required=True)
    init = sub.add_parser(
        "init", help="write campaign.toml from one subfolder per tree"
    )
    init.add_argument("folder", metavar="DIR")
    status = sub.add_parser(
        "status", help="one line per tree: its state and the decision on it"
    )
    status.add_argument("folder", metavar="DIR")
    decide = sub.add_parser(
        "decide", help="accept or reject trees, or clear the decision on them"
    )
    decide.add_argument("folder", metavar="DIR")
    decide.add_argument("trees", nargs="+", metavar="TREE", help="tree ids")
    decide.add_argument(
        "decision",
        choices=("accepted", "rejected", "clear"),
        metavar="DECISION",
        help="accepted, rejected or clear",
    )
    decide.add_argument(
        "--confirm-unregistered",
        action="store_true",
        help="accept trees the batch did not register (failed, needs review)",
    )
    export = sub.add_parser(
        "export", help="write the merged cloud of every accepted tree"
    )
    export.add_argument("folder", metavar="DIR")
    export.add_argument(
        "--format",
        default="ply",
        choices=("ply", "las", "laz", "pcd"),
        help="cloud format (default ply)",
    )
    sim = sub.add_parser(
        "simulate", help="several simulated scans of one tree, with truth"
    )
    simulate.configure_parser(sim)


def run_campaign(args: argparse.Namespace) -> int:
    """Run ``amrst campaign ACTION``."""
    from amrst.campaign.manifest import load_campaign
    from amrst.multiscan import simulate

    if args.campaign_command == "simulate":
        return simulate.run_cli(args)
    if args.campaign_command == "init":
        return _init(args.folder)
    campaign = load_campaign(args.folder)
    if args.campaign_command == "decide":
        return _decide(campaign, args)
    if args.campaign_command == "export":
        return _export(campaign, args.format)
    return _status(campaign)


def _init(folder: str) -> int:
    from amrst.campaign.init import init_campaign

    campaign, skipped = init_campaign(folder)
    print(f"{campaign.root / campaign.source}: {len(campaign.trees)} tree(s).")
    for t in campaign.trees:
        print(f"  {t.id}: {len(t.scans)} scans, reference {t.scans[t.reference]}")
    for line in skipped:
        print(f"  not paired: {line}")
    return 0


def _status(campaign: Campaign) -> int:
    """One line per tree: state, decision, confidence or error; then the counts."""
    from amrst.campaign.table import campaign_rows

    rows = campaign_rows(campaign)
    width = max((len(row["tree_id"]) for row in rows), default=0)
    for row in rows:
        extra = row["error"] or (
            f"confidence {row['confidence']:.0%}" if row["confidence"] != "" else ""
        )
        print(
            f"{row['tree_id']:<{width}}  {row['status']:<13} {row['decision']:<9} "
            f"{extra}".rstrip()
        )
    counts: dict[str, int] = {}
    for row in rows:
        for word in (row["status"], row["decision"]):
            if word:
                counts[word] = counts.get(word, 0) + 1
    print(", ".join(f"{n} {s}" for s, n in sorted(counts.items())))
    return 0


def _decide(campaign: Campaign, args: argparse.Namespace) -> int:
    from amrst.campaign.review import CLEAR, decide
    from amrst.campaign.table import TABLE

    decide(
        campaign,
        args.trees,
        args.decision,
        confirm_unregistered=args.confirm_unregistered,
    )
    what = "decision cleared" if args.decision == CLEAR else args.decision
    for tree_id in args.trees:
        print(f"{tree_id}: {what}")
    print(f"table: {campaign.root / TABLE}")
    return 0


def _export(campaign: Campaign, cloud_format: str) -> int:
    from amrst.campaign.review import export_accepted

    written, errors = export_accepted(campaign, cloud_format)
    for path in written:
        print(f"wrote {path}")
    for tree_id, error in errors.items():
        print(f"  {tree_id}: {error}", file=sys.stderr)
    if not written and not errors:
        print(
            "No tree is accepted yet: accept trees first "
            "(amrst campaign decide DIR TREE accepted)."
        )
    return EXIT_NOT_REGISTERED if errors else 0


def configure_batch(p: argparse.ArgumentParser) -> None:
    """Add the ``amrst batch`` arguments."""
    p.add_argument(
        "campaign", metavar="CAMPAIGN", help="campaign folder (with campaign.toml)"
    )
    from amrst.campaign.batch import DEFAULT_WORKERS

    p.add_argument(
        "--workers",
        type=int,
        default=DEFAULT_WORKERS,
        help="local worker processes, up to the machine's cores (default "
        f"{DEFAULT_WORKERS})",
    )
    p.add_argument(
        "--scheduler",
        metavar="ADDRESS",
        help="use a running dask scheduler (tcp://host:8786) instead of local workers",
    )
    p.add_argument(
        "--threads-per-tree",
        type=int,
        choices=(1, 2),
        metavar="N",
        help="threads each tree uses, 1 or 2 (default: 2 when each worker has two "
        "cores to itself, else 1)",
    )
    p.add_argument("--params", metavar="FILE", help="parameter JSON for every tree")
    p.add_argument(
        "--preset",
        metavar="NAME",
        help="a preset for every tree, as amrst register --preset takes it",
    )
    p.add_argument(
        "--force", action="store_true", help="re-register trees already done"
    )
    p.add_argument(
        "--tree", action="append", metavar="ID", help="only this tree (repeatable)"
    )
    p.add_argument(
        "--write-clouds",
        nargs="?",
        const="ply",
        default="",
        choices=("ply", "las", "laz", "pcd"),
        metavar="FORMAT",
        help="also write each tree's merged cloud (scan_id per point); default format ply",
    )
    p.add_argument("--quiet", action="store_true", help="no progress output")


def run_batch_cli(args: argparse.Namespace) -> int:
    """Run ``amrst batch``: register the campaign's pending trees."""
    from amrst.campaign.batch import run_batch
    from amrst.campaign.manifest import load_campaign
    from amrst.campaign.table import TABLE
    from amrst.errors import InvalidInput
    from amrst.params import load_params, load_preset

    if args.params and args.preset:
        raise InvalidInput("Give one of --params or --preset, not both.")
    params = (
        load_params(args.params)
        if args.params
        else load_preset(args.preset)
        if args.preset
        else None
    )
    campaign = load_campaign(args.campaign)
    summary = run_batch(
        campaign,
        workers=args.workers,
        scheduler=args.scheduler,
        params=params,
        force=args.force,
        progress=TerminalBar(args.quiet),
        only=args.tree,
        clouds=args.write_clouds,
        threads_per_tree=args.threads_per_tree,
    )
    print(
        f"{summary.counts()} in {summary.seconds:.1f} s; table: {campaign.root / TABLE}"
    )
    for tree_id, error in summary.errors.items():
        print(f"  {tree_id}: {error}", file=sys.stderr)
    return EXIT_NOT_REGISTERED if summary.errors else 0
