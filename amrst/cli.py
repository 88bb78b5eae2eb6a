"""The ``amrst`` command: ``info`` and ``register`` here, the rest in their modules.

Every AmrstError becomes one clear line on stderr and a non-zero exit code; a traceback
is shown only with --debug. A closed output pipe (``amrst info big.ply | head``) ends
the command quietly.
"""

from __future__ import annotations

import argparse
import logging
import math
import os
import shlex
import sys
import time
import warnings
from pathlib import Path
from typing import TYPE_CHECKING, Any, NoReturn

from amrst import __version__
from amrst.errors import (
    EXIT_CANCELLED,
    EXIT_INPUT,
    EXIT_NOT_REGISTERED,
    AmrstError,
    Cancelled,
    InvalidInput,
    RegistrationFailed,
)
from amrst.files.outcheck import same_file
from amrst.terminal import TerminalReporter

if TYPE_CHECKING:
    from collections.abc import Sequence

    from amrst.params import RegistrationParams
    from amrst.pipeline.register import RegistrationResult

EXIT_PIPE = 1  # stdout closed by the reader (Python's own code for EPIPE)

logger = logging.getLogger(__name__)


def _cmd_info(args: argparse.Namespace) -> int:
    from amrst import io
    from amrst.io.describe import format_scan_list
    from amrst.io.posed import check_indices
    from amrst.io.scans import SEVERAL_SCANS, list_scans, read_scans, split_spec

    for k, spec in enumerate(args.files):
        if k:
            print()
        path, wanted = split_spec(spec)
        if path.suffix.lower() in SEVERAL_SCANS:
            infos = list_scans(path)
            picked = check_indices(path, wanted, len(infos))
            if len(picked) > 1:
                print(format_scan_list(path.name, [infos[i] for i in picked]))
                continue
            spec = f"{path}#{picked[0]}"
        (cloud,) = read_scans(spec)
        print(io.format_description(io.describe(cloud)))
    return 0


def _load_params(args: argparse.Namespace) -> RegistrationParams:
    from amrst.params import RegistrationParams, load_params, load_preset

    # An unknown preset is refused first, whatever else was given.
    preset = load_preset(args.preset) if args.preset is not None else None
    if args.params is not None and preset is not None:
        raise InvalidInput(
            f"Both --preset {args.preset!r} and --params {args.params} were given; "
            "use one of --preset or --params."
        )
    if args.params is not None:
        return load_params(args.params)
    return preset if preset is not None else RegistrationParams()


def _print_summary(
    result: RegistrationResult,
    summary: dict[str, Any],
    names: tuple[str, str],
    t_read: float,
    *,
    files: tuple[str, str],
    stem_given: bool = False,
) -> None:
    """Print what a registration found: poses, quality, the tree, truth errors.

    Scans that hold a plot (unless a stem was given) are said to, with the
    ``amrst plot`` command for their ``files``; the merged figures are then the
    stem nearest the middle's.
    """
    fine = summary["fine"]
    cand = result.coarse.candidate
    print(
        f"Registered {names[1]} onto {names[0]} in {result.timings['total']:.2f} s "
        f"(read {t_read:.2f} s)."
    )
    print(
        f"  coarse: candidate {cand.rank} of {len(result.matches.candidates)}"
        f"{' (trunk heading search)' if cand.origin == 'trunk' else ''}"
        f"{' (point pairs)' if cand.origin == 'manual' else ''}, "
        f"verification score {cand.score:.0%}, confidence {result.confidence:.0%}"
    )
    print(
        f"  fine ({fine['method']}): NN-RMSE {fine['rmse_overlap_m'] * 100:.1f} cm in "
        f"the overlap, Hausdorff p95 {fine['hausdorff_p95_m']:.2f} m, overlap "
        f"{fine['overlap_fraction']:.0%}"
    )
    if result.overlap is not None and result.overlap.n_points_measured:
        o = result.overlap
        line = (
            f"  quality: where both scans saw the scene, median distance "
            f"{o.median_m * 100:.1f} cm, {o.within_2cm_fraction:.0%} within 2 cm"
        )
        if result.strength is not None and result.strength.weak:
            line += f"; weak axes: {', '.join(result.strength.weak)}"
        print(line)
    from amrst.stages.scene import plot_stems, stem_counts

    stems = (
        None
        if stem_given
        else plot_stems(stem_counts([result.target.scene, result.source.scene]))
    )
    plot = stems is not None
    if stems is not None:
        print(
            f"  the scans hold {stems[0]} and {stems[1]} stems: a plot, not one tree. "
            f"To list and measure every tree: amrst plot {shlex.join(files)} --out DIR"
        )
    if "merged" in result.tree:
        merged = result.tree["merged"]
        what = "the stem nearest the middle" if plot else "tree"
        print(f"  {what} (merged): {merged.summary()}")
        if merged.note:
            print(f"    {merged.note}")
        check = summary["tree"]["merged"].get("dbh_check", "ok")
        if check != "ok":
            print(f"    DBH doubtful: {check}")
    if "truth" in summary:
        tf = summary["truth"]["fine"]
        print(
            f"  truth: rotation error {tf['rotation_error_deg']:.3f} deg, translation "
            f"error {tf['translation_error_m'] * 100:.1f} cm, gt_rmse "
            f"{tf['gt_rmse_m'] * 100:.2f} cm -> "
            f"{'registered' if summary['truth']['registered'] else 'NOT registered'}"
        )


#: A stem found farther than this from the --stem given (m) is not the one meant.
STEM_MISS_M = 1.0


def _stems_missed(result: RegistrationResult, given: tuple[Any, Any]) -> list[str]:
    """Say where the tree measured stands far from the ``--stem`` given for a scan."""
    lines = []
    for flag, an, xy in zip(
        ("--stem", "--source-stem"), (result.target, result.source), given, strict=True
    ):
        scene = an.scene
        if xy is None or scene is None or not scene.has_ground:
            continue
        at = f"{flag} {xy[0]:g} {xy[1]:g}"
        if scene.base is None:
            lines.append(
                f"no stem found near {at}: the tree figures describe no one tree; "
                "check the position (the file's coordinates)."
            )
            continue
        found = [float(v) for v in scene.base[:2] + an.cloud.offset[:2]]
        miss = math.hypot(found[0] - xy[0], found[1] - xy[1])
        if miss > STEM_MISS_M:
            lines.append(
                f"no stem within {STEM_MISS_M:g} m of {at}: the tree measured "
                f"stands at {found[0]:.2f} {found[1]:.2f}, {miss:.1f} m away; check "
                "the position (the file's coordinates)."
            )
    return lines


def _other_inputs(args: argparse.Namespace) -> list[str]:
    """Return the files ``amrst register`` reads besides the scans."""
    given = (getattr(args, name, None) for name in ("truth", "pairs", "params"))
    return [str(f) for f in given if f]


def _register_scans(args: argparse.Namespace, params: RegistrationParams) -> int:
    """Hand ``amrst register`` with more than a pair of scans to amrst.multiscan."""
    from amrst.errors import InvalidInput
    from amrst.multiscan.cli import run_register

    pair_only = [
        flag
        for flag, name in (
            ("--pairs", "pairs"),
            ("--stem", "stem"),
            ("--source-stem", "source_stem"),
        )
        if getattr(args, name) is not None
    ]
    if pair_only:
        raise InvalidInput(
            f"{' and '.join(pair_only)} {'works' if len(pair_only) == 1 else 'work'} "
            "on two scan files (TARGET SOURCE), not on "
            "several scans or scans inside one file: give the two scans as two "
            "files, or for a plot use amrst plot ... --pairs I J PAIRS.csv."
        )

    return run_register(args, params, TerminalReporter(args.quiet))


def _cmd_register(args: argparse.Namespace) -> int:
    from amrst import io
    from amrst.files.outdir import folder_stamp
    from amrst.pipeline import register
    from amrst.results.documents import record_from_registration, result_documents
    from amrst.results.export import (
        MANAGED_NAMES,
        check_output_dir,
        export_registration,
        output_names,
        refuse_inputs_in_out,
        refuse_other_export,
    )
    from amrst.results.report_html import REPORT_NAME
    from amrst.review.pairs_file import read_pairs

    t_start = time.perf_counter()
    # Everything that can be checked without the clouds is checked before reading.
    params = _load_params(args)
    if args.format is not None and not args.write_clouds:
        raise InvalidInput(
            f"--format {args.format} sets the format of the clouds --write-clouds "
            "writes: add --write-clouds, or leave --format out."
        )
    args.format = args.format or "ply"
    if len(args.source) != 1 or "#" in args.target + "".join(args.source):
        return _register_scans(args, params)
    args.source = args.source[0]
    from amrst.guards import into_grid
    from amrst.io.checks import check_scans
    from amrst.io.truth import read_truth

    T_truth = read_truth(args.truth) if args.truth is not None else None
    parts = ["transform", "metrics", "params"] + (
        ["registered", "merged"] if args.write_clouds else []
    )
    report_name = [REPORT_NAME] if args.report else []
    check_output_dir(args.out, output_names(parts, args.format) + report_name)
    refuse_inputs_in_out(
        args.out, [str(args.target), str(args.source), *_other_inputs(args)]
    )
    refuse_other_export(
        args.out, [str(args.target), str(args.source)], overwrite=args.overwrite
    )
    # What the folder holds now is what this run may replace (not another run's).
    before = folder_stamp(args.out, [*MANAGED_NAMES, REPORT_NAME])
    pairs = read_pairs(Path(args.pairs)) if args.pairs else None
    if same_file(args.target, args.source):
        raise InvalidInput(
            f"TARGET and SOURCE are the same file ({args.target}): give two scans "
            "of the tree."
        )
    target, source = io.read(args.target), io.read(args.source)
    if any(c.meta.get("n_scans", 1) > 1 for c in (target, source)):
        # A file of several scans (E57, PTX) counts as its scans, never as one cloud.
        del target, source
        args.source = [args.source]
        return _register_scans(args, params)
    check_scans([target, source], [str(args.target), str(args.source)])
    for cloud, path in ((target, args.target), (source, args.source)):
        # the feature matcher's voxel grid bounds the span a scan may have
        into_grid(cloud.xyz, params.global_match.voxel_size_m, Path(path).name)
    t_read = time.perf_counter() - t_start
    reporter = TerminalReporter(args.quiet)
    if pairs is not None:
        from amrst.pipeline.manual import register_from_pairs

        result = register_from_pairs(target, source, pairs, params, reporter)
    else:
        stems = (args.stem, args.source_stem)  # --stem / --source-stem
        result = register(target, source, params, reporter, stems=stems)
    from amrst.review.verdict import FAILED, REGISTERED, judge_result

    verdict = judge_result(result, params)
    # One layout for the CLI, the app and the benchmark (amrst.results.documents).
    documents = result_documents(
        record_from_registration(
            result,
            T_truth,
            target_file=str(args.target),
            source_file=str(args.source),
            timings_s={"read": t_read},
            amrst_version=__version__,
            verdict=verdict.as_dict(),
        )
    )
    summary = documents.metrics
    extra_files = {}
    if args.report:  # the registration report, pictures drawn with Agg
        from amrst.files.atomic import text_writer
        from amrst.results.report_html import inputs_from_result, report_page

        report = inputs_from_result(
            result,
            target,
            source,
            target_file=str(args.target),
            source_file=str(args.source),
            T_truth=T_truth,
        )
        extra_files[REPORT_NAME] = text_writer(report_page(report))
    files = export_registration(
        args.out,
        target=target,
        source=source,
        T_target_source=result.T_target_source,
        params=params,
        cloud_format=args.format,
        parts=tuple(parts),
        remove_stale=True,
        documents=documents,
        unchanged=before,
        extra_files=extra_files,
    )
    _print_summary(
        result,
        summary,
        (target.name, source.name),
        t_read,
        files=(str(args.target), str(args.source)),
        stem_given=args.stem is not None or args.source_stem is not None,
    )
    print(
        f"  wrote {len(files)} files to {args.out}: " + ", ".join(f.name for f in files)
    )
    for line in _stems_missed(result, (args.stem, args.source_stem)):
        print(f"amrst register: {line}", file=sys.stderr)
    # One verdict, the same words as the app (amrst.review.verdict).
    if verdict.status == FAILED:
        print(
            f"Registration failed: {verdict.reason} The files above are marked "
            f'"verified": false. Next: {verdict.next_step}',
            file=sys.stderr,
        )
        return EXIT_NOT_REGISTERED
    if verdict.status != REGISTERED:
        print(f"  WARNING: {verdict.text()}", file=sys.stderr)
        return EXIT_NOT_REGISTERED
    print(f"  verdict: {verdict.text()}")
    return 0


class OneLineParser(argparse.ArgumentParser):
    """An argument parser whose errors are one line, as every other error of amrst.

    Its subcommands' parsers are of this class too (argparse makes them so).
    """

    def error(self, message: str) -> NoReturn:
        """Say what is wrong with the arguments in one line, and exit with 2."""
        self.exit(2, f"{self.prog}: {message} ({self.prog} --help lists them).\n")

    def parse_known_args(  # type: ignore[override]
        self, args: Sequence[str] | None = None, namespace: Any = None
    ) -> tuple[argparse.Namespace, list[str]]:
        """Parse as argparse does, but refuse an empty argument.

        As a path, "" would name the current folder.
        """
        given = sys.argv[1:] if args is None else list(args)
        if "" in given:
            self.error("an empty argument was given; give the path or value")
        return super().parse_known_args(given, namespace)


def build_parser() -> argparse.ArgumentParser:
    """Build the argument parser with all sub-commands."""
    from amrst import bench, clip
    from amrst.bench import scale  # dense pairs, per-stage time, memory
    from amrst.simulate import cli as simulate_cli

    p = OneLineParser(
        prog="amrst",
        description="Marker-free registration of two TLS scans of one tree (AMRST).",
    )
    p.add_argument("--version", action="version", version=f"amrst {__version__}")
    p.add_argument(
        "--debug", action="store_true", help="show tracebacks and debug logging"
    )
    sub = p.add_subparsers(dest="command", metavar="COMMAND")

    info = sub.add_parser(
        "info", help="points, bounds, spacing and attributes of point cloud files"
    )
    info.add_argument("files", nargs="+", metavar="FILE")
    info.set_defaults(func=_cmd_info)

    reg = sub.add_parser(
        "register",
        help="register SOURCE onto TARGET and write transform, metrics, parameters",
    )
    reg.add_argument(
        "target",
        metavar="TARGET",
        help="reference scan (LAS/LAZ, PLY, PCD, XYZ/TXT/CSV)",
    )
    reg.add_argument(
        "source",
        metavar="SOURCE",
        nargs="*",
        help="scan(s) to move into the target frame; FILE.e57#k picks scan k of a "
        "file, and a file of several scans alone gives them all",
    )
    reg.add_argument(
        "--out",
        required=True,
        metavar="DIR",
        help="output folder (created; checked before registering)",
    )
    reg.add_argument(
        "--params",
        metavar="FILE",
        help="parameter JSON (as written in params.json); not with --preset",
    )
    reg.add_argument(
        "--preset",
        metavar="NAME",
        help="a preset of resources/presets, by its file name (conifer, leafless...) "
        "or its name; not with --params",
    )
    reg.add_argument(
        "--truth", metavar="TRUTH.json", help="known T_target_source: adds truth errors"
    )
    reg.add_argument(
        "--write-clouds",
        action="store_true",
        help="also write the registered source and the merged cloud",
    )
    reg.add_argument(
        "--format",
        choices=("ply", "las", "laz", "pcd"),
        help="cloud format for --write-clouds (default ply)",
    )
    reg.add_argument(
        "--report",
        action="store_true",
        help="also write report.html: verdict, candidates, metrics, pictures (no "
        "display needed)",
    )
    reg.add_argument("--quiet", action="store_true", help="no progress output")
    reg.add_argument(
        "--pairs",
        metavar="PAIRS.csv",
        help="register from point pairs picked in both scans instead of the "
        "automatic match: columns target_x,target_y,target_z,source_x,source_y,"
        "source_z in the files' coordinates, at least 3 pairs spread over the tree "
        "(2 fix a levelled pair: a turn about the vertical and a shift)",
    )
    reg.add_argument(
        "--overwrite",
        action="store_true",
        help="replace an export of another pair of scans found in --out (the same "
        "pair's export is always replaced)",
    )
    for flag, role in (("--stem", "TARGET"), ("--source-stem", "SOURCE")):
        reg.add_argument(
            flag,
            nargs=2,
            type=float,
            metavar=("X", "Y"),
            help=f"stem of "
            f"the tree in {role} (world x y): picks it and cuts a plot scan around it "
            "(said when the stem found is over 1 m away)",
        )
    reg.set_defaults(func=_cmd_register)

    sim = sub.add_parser(
        "simulate",
        help="make virtual tripod scans with truth: two of one complete tree cloud, or "
        "with --plot a forest plot of several trees from N positions",
    )
    simulate_cli.configure_parser(sim)
    sim.set_defaults(func=simulate_cli.run_cli)

    from amrst.plot import cli as plot_cli  # amrst plot

    plot = sub.add_parser(
        "plot",
        help="register the scans of a forest plot by its stems and list its trees",
    )
    plot_cli.configure_parser(plot)
    plot.set_defaults(func=plot_cli.run_cli)

    cut = sub.add_parser(
        "clip", help="cut one tree (a cylinder around its stem) out of a plot file"
    )
    clip.configure_parser(cut)
    cut.set_defaults(func=clip.run_cli)

    ben = sub.add_parser(
        "bench",
        help="run AMRST and the baselines on registration cases; write tables and plots",
    )
    bench.configure_parser(ben)
    ben.set_defaults(func=bench.run_cli)

    sca = sub.add_parser(
        "bench-scale", help="time amrst register (or amrst plot) on densified scans"
    )
    scale.configure_parser(sca)
    sca.set_defaults(func=scale.run_cli)

    from amrst.campaign import cli as campaign_cli  # amrst campaign / amrst batch

    cam = sub.add_parser("campaign", help="a folder of trees: init, status, simulate")
    campaign_cli.configure_campaign(cam)
    cam.set_defaults(func=campaign_cli.run_campaign)
    bat = sub.add_parser("batch", help="register every tree of a campaign on Dask")
    campaign_cli.configure_batch(bat)
    bat.set_defaults(func=campaign_cli.run_batch_cli)
    return p


def _silence_stdout() -> None:
    """Point stdout at devnull, so the exit flush does not fail on a closed pipe again.

    The recipe of the Python documentation (signal module, note on SIGPIPE).
    """
    try:
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())
    except (OSError, ValueError, AttributeError):  # no real file descriptor (tests)
        pass


def main(argv: list[str] | None = None) -> int:
    """Entry point of the ``amrst`` command.

    Parameters
    ----------
    argv : list of str or None
        The arguments; None reads ``sys.argv``.

    Returns
    -------
    int
        The exit code: 0 done, 1 internal error or closed output pipe, 2 unusable
        input, 3 not registered (failed or needs review; ``batch`` and ``campaign
        export``: a tree stopped with an error), 130 cancelled (``amrst.errors``).
    """
    try:
        code = _main(argv)
        sys.stdout.flush()  # a closed pipe shows here, not in the exit flush
    except BrokenPipeError:
        _silence_stdout()
        return EXIT_PIPE
    except KeyboardInterrupt:  # a second Ctrl+C, while the first is handled
        print("Interrupted.", file=sys.stderr)
        return EXIT_CANCELLED
    return code


def _main(argv: list[str] | None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    logging.basicConfig(
        level=logging.DEBUG if args.debug else logging.WARNING,
        format="%(levelname)s: %(message)s",
    )
    if not getattr(args, "func", None):
        parser.print_help()
        return 0
    # Library noise (numpy RuntimeWarnings, laspy's) never reaches the user: every
    # problem worth telling is an AmrstError or a logged line. --debug
    # shows the warnings as log lines.
    with warnings.catch_warnings():
        if args.debug:
            logging.captureWarnings(True)
        else:
            warnings.simplefilter("ignore")
        return _run(args)


def _run(args: argparse.Namespace) -> int:
    try:
        return int(args.func(args) or 0)
    except BrokenPipeError:
        raise  # main() ends quietly
    except Cancelled:
        print("Cancelled.", file=sys.stderr)
        return EXIT_CANCELLED
    except KeyboardInterrupt:
        print("Interrupted.", file=sys.stderr)
        return EXIT_CANCELLED
    except RegistrationFailed as exc:
        print(f"Registration failed: {exc}", file=sys.stderr)
        return EXIT_NOT_REGISTERED
    except Exception as exc:  # last line of defence: never a raw traceback for users
        message, code = _explain(exc, args)
        if message is None:
            raise
        print(message, file=sys.stderr)
        return code


def _explain(exc: Exception, args: argparse.Namespace) -> tuple[str | None, int]:
    """Give the one line and exit code for an error; no line: re-raise (--debug).

    The line starts with the command, as the commands that report their own errors
    (``amrst plot: ...``) do.
    """
    head = f"amrst {args.command}:"
    if isinstance(exc, AmrstError):
        return f"{head} {exc}", EXIT_INPUT
    if isinstance(exc, MemoryError):
        return (
            f"{head} out of memory. Thin the clouds first (e.g. a larger preprocess "
            "voxel size).",
            EXIT_INPUT,
        )
    if args.debug:
        return None, 1
    if isinstance(exc, ImportError):
        from amrst.extras import missing_extra

        found = missing_extra(exc, f"amrst {args.command}")
        if found is not None:
            return f"{head} {found}", EXIT_INPUT
    if isinstance(exc, OSError):  # a file-system refusal no check put in words
        where = f" ({exc.filename})" if exc.filename else ""
        return (
            f"{head} {exc.strerror or exc}{where}. Check the path, its length and "
            "its permissions, or choose another file or folder.",
            EXIT_INPUT,
        )
    return (
        f"Internal error: {type(exc).__name__}: {exc}. Run again with --debug and "
        "report it.",
        1,
    )


if __name__ == "__main__":
    sys.exit(main())
