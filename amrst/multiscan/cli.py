"""``amrst register REF SCAN2 SCAN3 ...``: more than two scans (or ``FILE.e57#k`` specs).

amrst.cli hands the parsed arguments here when more than two scans are given; the
options are those of the pair command (--out, --params/--preset, --truth,
--write-clouds, --format, --report, --quiet). ``--report`` writes report.html: the
pair report for two scans, else :mod:`amrst.results.report_multi` (every link with its
state and score, every scan with its path).
"""

from __future__ import annotations

import shlex
import sys
import time
from typing import TYPE_CHECKING

from amrst.errors import EXIT_NOT_REGISTERED
from amrst.io.checks import check_scans

if TYPE_CHECKING:
    import argparse

    from amrst.multiscan.register import MultiScanResult
    from amrst.params import RegistrationParams
    from amrst.progress import Reporter
    from amrst.types import Cloud


def read_specs(labels: list[str]) -> list[Cloud]:
    """Read the scans of one-scan specs (:func:`amrst.io.scans.one_scan_specs`)."""
    from amrst.io.scans import read_scans

    return [read_scans(label)[0] for label in labels]


def describe(result: MultiScanResult, labels: list[str]) -> list[str]:
    """Human lines: every link with its state, every scan with its path."""
    lines = []
    for link in result.links:
        rmse = (
            ""
            if link.metrics is None
            else f", NN-RMSE {link.metrics.rmse_overlap_m * 100:.1f} cm, overlap {link.metrics.overlap_fraction:.0%}"
        )
        used = " [tree]" if link.in_tree else ""
        lines.append(
            f"  link {link.target}-{link.source}: {link.status}, score {link.score:.0%}, "
            f"confidence {link.confidence:.0%}{rmse}{used}"
        )
    for k, label in enumerate(labels):
        path = result.paths[k]
        how = (
            "reference"
            if k == result.reference
            else (
                "NOT reached (no verified link)"
                if path is None
                else "via " + " -> ".join(map(str, path))
            )
        )
        lines.append(f"  scan {k} ({label}): {how}")
    if result.joint is not None:
        j = result.joint
        lines.append(
            f"  joint refinement: mean NN-RMSE {j.rmse_before_m * 100:.2f} -> "
            f"{j.rmse_after_m * 100:.2f} cm ({'kept' if j.kept else 'not kept: worse'})"
        )
    from amrst.stages.scene import plot_stems

    stems = plot_stems(result.stems)
    if stems is not None:
        lines.append(
            f"  the scans hold {', '.join(map(str, stems))} stems: a plot, not one "
            f"tree. To list and measure every tree: amrst plot {shlex.join(labels)} "
            "--out DIR"
        )
    if "merged" in result.tree:
        what = "the reference's stem nearest its middle" if stems else "tree"
        lines.append(f"  {what} (merged): {result.tree['merged'].summary()}")
    return lines


def run_register(
    args: argparse.Namespace, params: RegistrationParams, reporter: Reporter
) -> int:
    """Register every scan of ``args.target`` + ``args.source`` and write ``args.out``."""
    from amrst.errors import InvalidInput
    from amrst.io.scans import one_scan_specs
    from amrst.multiscan.export import (
        SUMMARY,
        export_scans,
        export_stamp,
        read_scan_truth,
    )
    from amrst.multiscan.register import register_scans
    from amrst.results.export import (
        MANAGED_NAMES,
        check_output_dir,
        refuse_inputs_in_out,
        refuse_other_export,
    )
    from amrst.results.report_html import REPORT_NAME
    from amrst.review.verdict import FAILED, REGISTERED

    report = bool(getattr(args, "report", False))
    check_output_dir(args.out, [REPORT_NAME] if report else [])
    labels = [spec for spec, _name in one_scan_specs([args.target, *args.source])]
    if len(labels) < 2:
        raise InvalidInput(
            "Two scans or more are needed: TARGET and SOURCE, or one file of "
            "several scans (E57, PTX)."
        )
    refuse_inputs_in_out(
        args.out,
        [*labels, *(str(f) for f in (args.truth, args.params) if f)],
        lambda name: (
            name in (*MANAGED_NAMES, REPORT_NAME, SUMMARY)
            or name.startswith("transform_")
        ),
    )
    refuse_other_export(args.out, labels, overwrite=bool(args.overwrite))
    # What the folder holds now is what this run may replace (not another run's).
    before = export_stamp(args.out, len(labels))
    t0 = time.perf_counter()
    clouds = read_specs(labels)
    check_scans(clouds, labels)
    truth = None
    if args.truth is not None:
        truth = read_scan_truth(args.truth, len(clouds), 0)
    result = register_scans(clouds, 0, params, reporter)
    files = export_scans(
        args.out,
        result,
        files=labels,
        truth=truth,
        clouds=args.write_clouds,
        cloud_format=args.format,
        unchanged=before,
        report=report,
    )
    print(
        f"Registered {len(clouds)} scans onto {labels[0]} in "
        f"{time.perf_counter() - t0:.2f} s: {result.status}."
    )
    for line in describe(result, labels):
        print(line)
    print(
        f"  wrote {len(files)} files to {args.out}: " + ", ".join(f.name for f in files)
    )
    if not all(result.reached) or result.status == FAILED:
        alone = [labels[k] for k, ok in enumerate(result.reached) if not ok]
        which = f": {', '.join(alone)}" if alone else ""
        print(
            f"{result.status.capitalize()}: no verified link reaches some scans"
            f"{which}. Check that they show the same tree, or review the links in "
            "amrst-gui.",
            file=sys.stderr,
        )
        return EXIT_NOT_REGISTERED
    if result.status != REGISTERED:
        print(
            f"  WARNING: {result.status}: the weakest link has confidence "
            f"{result.confidence:.0%}; compare the links in amrst-gui.",
            file=sys.stderr,
        )
        return EXIT_NOT_REGISTERED
    return 0
