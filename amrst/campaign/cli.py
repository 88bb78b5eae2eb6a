"""``amrst campaign init|status|simulate`` and ``amrst batch``.

amrst.cli adds these with a few lines: ``configure_campaign`` / ``run_campaign`` for
``amrst campaign``, ``configure_batch`` / ``run_batch_cli`` for ``amrst batch``.
"""

from __future__ import annotations

import sys
import time
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    import argparse

EXIT_FAILED = 3


class TerminalBar:
    """Trees done, failed, running and the time left, on stderr."""

    def __init__(self, quiet: bool = False) -> None:
        self._tty = sys.stderr.isatty()
        self._quiet = quiet
        self._t0 = time.perf_counter()

    def update(
        self,
        done: int,
        failed: int,
        running: int,
        total: int,
        left_s: float | None,
        row: dict[str, Any] | None,
    ) -> None:
        """Redraw the bar (terminal) or write one line per finished tree."""
        if self._quiet:
            return
        left = "" if left_s is None else f", {_clock(left_s)} left"
        text = f"{done}/{total} trees done, {failed} failed, {running} running{left}"
        if self._tty:
            share = (done + failed) / total if total else 1.0
            bar = "#" * int(30 * share)
            sys.stderr.write(f"\r[{bar:<30}] {text:<70}")
            if done + failed >= total:
                sys.stderr.write("\n")
        elif row is not None:
            what = (
                row.get("verdict")
                if row.get("ok")
                else f"FAILED: {row.get('error', '')}"
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
    """Add ``init``, ``status`` and ``simulate`` under ``amrst campaign``."""
    from amrst.multiscan import simulate

    sub = p.add_subparsers(dest="campaign_command", metavar="ACTION", required=True)
    init = sub.add_parser(
        "init", help="write campaign.toml from one subfolder per tree"
    )
    init.add_argument("folder", metavar="DIR")
    status = sub.add_parser("status", help="one line per tree: done, failed, not run")
    status.add_argument("folder", metavar="DIR")
    sim = sub.add_parser(
        "simulate", help="several simulated scans of one tree, with truth"
    )
    simulate.configure_parser(sim)


def run_campaign(args: argparse.Namespace) -> int:
    """Run ``amrst campaign ACTION``."""
    from amrst.campaign.init import init_campaign
    from amrst.campaign.manifest import load_campaign
    from amrst.campaign.table import campaign_rows
    from amrst.multiscan import simulate

    if args.campaign_command == "simulate":
        return simulate.run_cli(args)
    if args.campaign_command == "init":
        campaign, skipped = init_campaign(args.folder)
        print(f"{campaign.root / campaign.source}: {len(campaign.trees)} tree(s).")
        for t in campaign.trees:
            print(f"  {t.id}: {len(t.scans)} scans, reference {t.scans[t.reference]}")
        for line in skipped:
            print(f"  not paired: {line}")
        return 0
    campaign = load_campaign(args.folder)
    rows = campaign_rows(campaign)
    for row in rows:
        extra = row["error"] or (
            f"confidence {row['confidence']:.2f}" if row["confidence"] != "" else ""
        )
        print(f"{row['tree_id']:<24} {row['status']:<13} {extra}")
    counts: dict[str, int] = {}
    for row in rows:
        counts[row["status"]] = counts.get(row["status"], 0) + 1
    print(", ".join(f"{n} {s}" for s, n in sorted(counts.items())))
    return 0


def configure_batch(p: argparse.ArgumentParser) -> None:
    """Add the ``amrst batch`` arguments."""
    p.add_argument(
        "campaign", metavar="CAMPAIGN", help="campaign folder (with campaign.toml)"
    )
    p.add_argument(
        "--workers", type=int, default=2, help="local worker processes (default 2)"
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
    p.add_argument("--preset", metavar="NAME", help="a named preset for every tree")
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
        f"{len(summary.registered)} registered, {len(summary.failed)} failed, "
        f"{len(summary.skipped)} already done (skipped) in {summary.seconds:.1f} s; "
        f"table: {campaign.root / TABLE}"
    )
    for tree_id, error in summary.failed.items():
        print(f"  {tree_id}: {error}", file=sys.stderr)
    return EXIT_FAILED if summary.failed else 0
