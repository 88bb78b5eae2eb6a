"""``amrst bench``: argument parsing and a terminal progress bar on stderr."""

from __future__ import annotations

import shlex
import sys
import time
from pathlib import Path
from typing import TYPE_CHECKING, TextIO

if TYPE_CHECKING:
    import argparse
    from collections.abc import Sequence

#: Most runs per pair (--repeat): enough for a median, not a run of days.
MAX_REPEAT = 100


class TerminalProgress:
    """A one-line progress bar on a terminal stream: bar, message, elapsed time.

    Implements the :class:`amrst.progress.Reporter` protocol (never cancels; Ctrl+C
    stops the run as usual).

    Parameters
    ----------
    stream : text stream
        Usually ``sys.stderr``.
    width : int
        Characters of the bar.
    """

    def __init__(self, stream: TextIO | None = None, width: int = 24) -> None:
        self._stream = stream if stream is not None else sys.stderr
        self._width = width
        self._start = time.perf_counter()
        self._tty = bool(getattr(self._stream, "isatty", lambda: False)())

    def progress(self, fraction: float, message: str = "") -> None:
        """Redraw the bar (a new line per update when the stream is not a terminal)."""
        fraction = min(max(float(fraction), 0.0), 1.0)
        filled = round(fraction * self._width)
        elapsed = int(time.perf_counter() - self._start)
        line = (
            f"[{'#' * filled}{'.' * (self._width - filled)}] {fraction:4.0%} "
            f"{elapsed // 60:d}:{elapsed % 60:02d}  {message}"
        )
        if self._tty:
            self._stream.write("\r\x1b[2K" + line[:160])
            if fraction >= 1.0:
                self._stream.write("\n")
        else:
            self._stream.write(line + "\n")
        self._stream.flush()

    def check_cancelled(self) -> None:
        """Never cancels."""


def configure_parser(p: argparse.ArgumentParser) -> None:
    """Add the ``amrst bench`` arguments to ``p``.

    Parameters
    ----------
    p : argparse.ArgumentParser
    """
    from amrst.bench.run import DEFAULT_METHODS

    p.add_argument(
        "cases_dir",
        metavar="CASES_DIR",
        help="folder of case folders (plot cases, whose truth lists the stems, "
        "run amrst plot and, of --methods, kiss_gicp with a 0.2 m voxel and "
        "fpfh_ransac)",
    )
    p.add_argument(
        "--methods",
        nargs="+",
        default=list(DEFAULT_METHODS),
        metavar="NAME",
        help=f"methods to run (default: all: {' '.join(DEFAULT_METHODS)})",
    )
    p.add_argument("--out", default="bench_out", metavar="DIR", help="output folder")
    p.add_argument(
        "--overwrite",
        action="store_true",
        help="replace the results an earlier run wrote into --out",
    )
    p.add_argument("--repeat", type=int, default=1, metavar="N", help="runs per pair")
    p.add_argument("--cases", default=None, metavar="PATTERN", help="e.g. '*normal*'")
    p.add_argument("--no-plots", action="store_true", help="skip the PNG plots")


def run_cli(args: argparse.Namespace) -> int:
    """Run the benchmark from parsed ``args``; print where the results went.

    Parameters
    ----------
    args : argparse.Namespace

    Returns
    -------
    int
        0 when it ran (even if methods failed on cases), 2 on unusable input,
        130 when interrupted.
    """
    from amrst.bench.plot import is_plot_case
    from amrst.bench.run import no_cases_message, resolve_methods, run_bench
    from amrst.errors import AmrstError, InvalidInput
    from amrst.files.outcheck import check_outside
    from amrst.io.cases import find_cases

    try:
        if not 1 <= args.repeat <= MAX_REPEAT:
            raise InvalidInput(
                f"--repeat must be 1 to {MAX_REPEAT}, got {args.repeat}."
            )
        resolve_methods(args.methods)  # an unknown name, on plot cases too
        folders = find_cases(args.cases_dir, args.cases)
        if args.cases and not folders:
            raise InvalidInput(no_cases_message(args.cases_dir, args.cases))
        if not folders:
            raise InvalidInput(
                f"No case folders (with truth.json) under {args.cases_dir}: give the "
                "folder that holds them (each with a target.* and a source.* scan "
                "and truth.json), or make cases with 'amrst simulate'."
            )
        plots = sum(is_plot_case(f) for f in folders)
        if 0 < plots < len(folders):
            raise InvalidInput(
                f"{args.cases_dir} holds {plots} plot case(s) among {len(folders)} "
                "(the others are tree pairs, or their truth.json cannot be read): a "
                "plot runs amrst plot, a pair amrst register; bench them apart with "
                "--cases PATTERN."
            )
        check_outside(args.out, args.cases_dir, "cases folder")
        check_out(Path(args.out), args.overwrite)
    except AmrstError as exc:
        print(f"amrst bench: {exc}", file=sys.stderr)
        return 2
    if plots:
        return _run_plot_bench(args)
    command = shlex.join(["amrst", "bench", *sys.argv[2:]]) if len(sys.argv) > 1 else ""
    try:
        result = run_bench(
            args.cases_dir,
            args.methods,
            args.out,
            args.repeat,
            TerminalProgress(),
            pattern=args.cases,
            command=command,
            plots=not args.no_plots,
        )
    except (KeyboardInterrupt, AmrstError) as exc:
        return _stopped(exc)
    ok = sum(r.success for r in result.runs)
    unreadable = result.meta.get("unreadable_cases") or {}
    skipped = (
        f"; {len(unreadable)} case(s) could not be read and count as failed "
        f"({', '.join(unreadable)})"
        if unreadable
        else ""
    )
    print(
        f"{len(result.runs)} runs, {ok} registered{skipped}; "
        f"summary: {result.out_dir / 'summary.md'}",
        file=sys.stderr,
    )
    if unreadable and len(unreadable) == len(folders):
        print(
            "amrst bench: no case could be read: nothing was measured.", file=sys.stderr
        )
        return 2
    return 0


#: The files a run writes into --out that an earlier run's results are read from.
RESULT_FILES = ("summary.md", "results.json", "results.csv", "plot_results.json")


def check_out(
    out: Path, overwrite: bool, result_files: Sequence[str] = RESULT_FILES
) -> None:
    """Refuse an ``out`` this process cannot write in, or of an earlier run.

    An earlier run's results are replaced only with ``overwrite``.

    Parameters
    ----------
    out : Path
        The ``--out`` folder.
    overwrite : bool
        ``--overwrite`` was given.
    result_files : sequence of str
        The files of a run that mark an earlier one.

    Raises
    ------
    InvalidInput
        With what to change.
    """
    from amrst.errors import InvalidInput
    from amrst.files.outcheck import check_output_folder

    held = [name for name in result_files if (out / name).exists()]
    if held and not overwrite:
        raise InvalidInput(
            f"{out} holds the results of an earlier run ({held[0]}): give another "
            "folder (--out DIR), or --overwrite to replace them."
        )
    check_output_folder(out, "output folder")  # before the cases run, not after


def _stopped(exc: BaseException) -> int:
    """Say why a bench run stopped early, in one line; return the exit code."""
    if isinstance(exc, KeyboardInterrupt):
        print(
            "\namrst bench: interrupted; partial results are in the output folder.",
            file=sys.stderr,
        )
        return 130
    print(f"amrst bench: {exc}", file=sys.stderr)
    return 2


def _run_plot_bench(args: argparse.Namespace) -> int:
    """Plot cases: ``amrst plot`` and the baselines per scan, and the inventory."""
    from amrst.bench.plot import FPFH, KISS, PLOT, run_plot_bench
    from amrst.errors import AmrstError

    # The pair methods' names, as on tree cases; the others have no plot form.
    named = {"amrst": PLOT, "kiss_gicp": KISS, "fpfh_ransac": FPFH}
    methods = [named[m] for m in args.methods if m in named] or [PLOT]
    try:
        records = run_plot_bench(
            args.cases_dir,
            args.out,
            TerminalProgress(),
            pattern=args.cases,
            methods=methods,
        )
    except (KeyboardInterrupt, AmrstError) as exc:
        return _stopped(exc)
    print(f"{len(records)} plot runs; summary: {args.out}/summary.md", file=sys.stderr)
    return 0
