"""Cut one tree out of a big plot file: ``amrst clip FILE --stem X Y --radius R``.

A technician receives one file per plot (a merged or single-position scan of
millions of points) and registers tree by tree. :func:`clip_tree` keeps the points
within a radius of a stem (optionally between two heights), reading only what the
format allows: the octree nodes near the stem of a COPC file, chunk after chunk of
a LAS/LAZ file (bounded memory), the whole file otherwise (see
:func:`amrst.io.read_region`).
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

from amrst.progress import NULL_REPORTER

if TYPE_CHECKING:
    import argparse

    from amrst.progress import Reporter
    from amrst.types import Cloud


@dataclass(frozen=True, slots=True, kw_only=True)
class ClipParams:
    """Where the tree of interest stands and how much of it to keep."""

    stem_xy: tuple[float, float]  # world coordinates of the file (m)
    radius_m: float = 5.0
    zmin: float | None = None  # world heights (m); None: unbounded
    zmax: float | None = None


@dataclass(frozen=True, slots=True)
class ClipResult:
    """The tree, and how much of the file was decoded to find it."""

    cloud: Cloud
    method: str  # "copc spatial query" | "streamed chunks" | "whole file"
    points_decoded: int
    seconds: float


def clip_tree(
    path: str | Path, params: ClipParams, reporter: Reporter = NULL_REPORTER
) -> ClipResult:
    """Read the points of ``path`` within ``params.radius_m`` of the stem.

    Parameters
    ----------
    path : str or Path
        A plot file in any readable format.
    params : ClipParams
    reporter : Reporter
        Progress and cancellation.

    Returns
    -------
    ClipResult

    Raises
    ------
    InvalidInput
        Unreadable file, bad radius or heights, or no point near the stem.
    """
    from amrst import io

    start = time.perf_counter()
    cloud = io.read_region(
        path,
        params.stem_xy,
        params.radius_m,
        zmin=params.zmin,
        zmax=params.zmax,
        reporter=reporter,
    )
    return ClipResult(
        cloud,
        str(cloud.meta.get("clip_method", "")),
        int(cloud.meta.get("clip_points_decoded", len(cloud))),
        time.perf_counter() - start,
    )


def out_paths(out: str | Path, n_stems: int) -> list[Path]:
    """One output per stem: ``out`` itself, or ``NAME_1.ext``, ``NAME_2.ext``..."""
    out = Path(out)
    if n_stems == 1:
        return [out]
    return [out.with_name(f"{out.stem}_{i}{out.suffix}") for i in range(1, n_stems + 1)]


def _check_outs(source: Path, outs: list[Path], overwrite: bool) -> None:
    """Refuse to write over the file clipped, or over files that exist unless asked."""
    from amrst.errors import InvalidInput
    from amrst.files.outcheck import same_file

    for out in outs:
        if same_file(out, source):
            raise InvalidInput(
                f"{out} is the file being clipped: choose another --out name."
            )
        if out.is_dir():
            raise InvalidInput(f"{out} is a folder: give --out a file name.")
        if (out.exists() or out.is_symlink()) and not overwrite:
            raise InvalidInput(
                f"{out} exists: choose another --out name, or add --overwrite to "
                "replace it."
            )


def configure_parser(p: argparse.ArgumentParser) -> None:
    """Add the ``amrst clip`` arguments to ``p``.

    Parameters
    ----------
    p : argparse.ArgumentParser
    """
    p.add_argument("file", metavar="FILE", help="plot file (any readable format)")
    p.add_argument(
        "--stem",
        nargs=2,
        type=float,
        action="append",
        required=True,
        metavar=("X", "Y"),
        help="stem position in the file's coordinates; repeat for several trees",
    )
    p.add_argument(
        "--radius",
        type=float,
        default=5.0,
        metavar="R",
        help="m around each stem (default 5)",
    )
    p.add_argument("--zmin", type=float, default=None, help="lowest height kept (m)")
    p.add_argument("--zmax", type=float, default=None, help="highest height kept (m)")
    p.add_argument(
        "--out",
        required=True,
        metavar="TREE.laz",
        help="output file; with several stems TREE_1.laz, TREE_2.laz, ...",
    )
    p.add_argument(
        "--overwrite", action="store_true", help="replace output files that exist"
    )


def run_cli(args: argparse.Namespace) -> int:
    """Clip one tree per ``--stem`` from ``args`` (see :func:`configure_parser`).

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
    from amrst.errors import AmrstError, InvalidInput
    from amrst.io.region import check_cylinder

    outs = out_paths(args.out, len(args.stem))
    try:
        # The output is checked before the (possibly long) read.
        if io.get_reader(args.out) is None or Path(args.out).suffix.lower() not in (
            io.writable_extensions()
        ):
            raise InvalidInput(
                f"Cannot write {args.out}: choose a name ending in "
                f"{', '.join(io.writable_extensions())}."
            )
        if not outs[0].parent.is_dir():
            what = "is a file" if outs[0].parent.exists() else "does not exist"
            raise InvalidInput(
                f"Cannot write {args.out}: the folder {outs[0].parent} {what}. "
                "Create the folder or choose another one."
            )
        _check_outs(Path(args.file), outs, args.overwrite)
        for xy in args.stem:  # every stem before the first cut
            check_cylinder(xy, args.radius, args.zmin, args.zmax)
        # Each tree goes to a hidden file first, and they take their names only once
        # every stem is cut: a stem with no points near it leaves no file behind,
        # and memory holds one tree at a time.
        parts = [out.with_name(f".{out.stem}.amrst-part{out.suffix}") for out in outs]
        said = []
        try:
            for (x, y), out, part in zip(args.stem, outs, parts, strict=True):
                params = ClipParams(
                    stem_xy=(x, y), radius_m=args.radius, zmin=args.zmin, zmax=args.zmax
                )
                result = clip_tree(args.file, params)
                io.write(part, result.cloud)
                said.append(
                    f"{out}: {len(result.cloud):,} points within {args.radius:g} m "
                    f"of ({x:g}, {y:g}); {result.method}, {result.points_decoded:,} "
                    f"points decoded in {result.seconds:.2f} s"
                )
            for out, part in zip(outs, parts, strict=True):
                part.replace(out)
            print("\n".join(said), file=sys.stderr)  # once every file is there
        finally:
            for part in parts:
                part.unlink(missing_ok=True)
    except AmrstError as exc:
        print(f"amrst clip: {exc}", file=sys.stderr)
        return 2
    return 0
