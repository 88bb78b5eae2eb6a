"""What each workflow step runs in its worker: engine calls only, no Qt.

Each function takes its inputs (frozen engine objects), then the reporter last,
and returns ``(result, seconds)``. The session hands them to
``workers.run_stage`` and applies the result on the GUI thread.
"""

from __future__ import annotations

import os
import time
from pathlib import Path
from typing import TYPE_CHECKING, Any

from amrst.errors import InvalidInput
from amrst.progress import NULL_REPORTER, Reporter, SubReporter

if TYPE_CHECKING:
    import numpy as np

    from amrst.pipeline.refine import PoseQuality
    from amrst.review.manual_keep import KeepDecision

ROLES = ("target", "source")

# Threads of the engine's steps in the app: every core but one, two at most, so
# that the window keeps a core for itself. The results do not depend on them.
THREADS = max(1, min(2, (os.cpu_count() or 1) - 1))


def load_pair(
    paths: dict[str, Path], reporter: Reporter, min_points: int = 0
) -> tuple[dict, float]:
    """Read the scans in ``paths`` (role -> path) with ``amrst.io.read``; refuse one
    whose coordinates are not metres or come in coarse steps, or that holds fewer
    than ``min_points`` points (what Separate needs at the least)."""
    from amrst import io
    from amrst.io.checks import refuse_odd_coordinates

    start = time.perf_counter()
    clouds = {}
    for i, (role, path) in enumerate(paths.items()):
        reporter.check_cancelled()
        reporter.progress(i / len(paths), f"Reading {role} {Path(path).name}")
        # LAS/LAZ are read in chunks with a cancel check between them.
        sub = SubReporter(
            reporter, i / len(paths), (i + 1) / len(paths), f"Reading {role}"
        )
        # FILE#k: one scan of an E57/PTX file (a campaign tree of one file)
        if is_scan_spec(path):
            clouds[role] = read_scan(path)
        else:
            clouds[role] = io.read(path, reporter=sub)
            refuse_several(clouds[role], Path(path).name)
        refuse_odd_coordinates(clouds[role], Path(path).name)
        if len(clouds[role]) < min_points:
            raise InvalidInput(
                f"{Path(path).name} holds {len(clouds[role])} point(s); a scan needs "
                f"at least {min_points} (preprocess min points): open a whole scan."
            )
    reporter.progress(1.0, "Scans read")
    return clouds, time.perf_counter() - start


def describe_scan(cloud: Any, reporter: Reporter) -> str:
    """``amrst.io.describe(cloud)`` as text for the Scans dock (bounds and a
    nearest-neighbour spacing: seconds on ten million points); "" if it fails,
    since the description is informative only."""
    from amrst import io

    reporter.check_cancelled()
    try:
        return str(io.describe(cloud))
    except Exception:
        return ""


def is_scan_spec(path: Path) -> bool:
    """Tell whether ``path`` names one scan of a multi-scan file (``plot.e57#2``)."""
    from amrst.errors import AmrstError
    from amrst.io.scans import split_spec

    try:
        file, scans = split_spec(path)
    except AmrstError:
        return False
    return scans is not None and len(scans) == 1 and file.is_file()


def refuse_several(cloud: Any, name: str) -> None:
    """Refuse a cloud read from a file of several scans as one scan of a pair: its
    scans would be registered as one."""
    from amrst.errors import InvalidInput

    n = cloud.meta.get("n_scans", 1)
    if n > 1:
        raise InvalidInput(
            f"{name} holds {n} scans, one position each: open it in the Plot window "
            f"(File ▸ Open plot…), which lists them, or register them all with "
            f"'amrst register {name} --out DIR'."
        )


def read_scan(spec: Path) -> Any:
    """Read the one scan a ``FILE#k`` spec names (a campaign's E57/PTX trees)."""
    from amrst.io.scans import read_scans

    return read_scans(spec)[0]


def _both(
    step: Any, items: dict, params: Any, reporter: Reporter
) -> tuple[dict, float]:
    """Run ``step(item, params, reporter)`` on both scans; results by role."""
    from amrst import pipeline

    start = time.perf_counter()
    out = pipeline.both_scans(
        lambda item, rep: step(item, params, rep, threads=THREADS),
        items["target"],
        items["source"],
        reporter,
    )
    return dict(zip(ROLES, out, strict=True)), time.perf_counter() - start


class SameScans(InvalidInput):
    """The target and the source hold the same points: no parameter would help."""


def separate_pair(clouds: dict, params: Any, reporter: Reporter) -> tuple[dict, float]:
    """Preprocess and separate wood from leaves in both scans.

    Refuses the same scan twice (a copy, the scan exported again) first: compared
    point by point, here in the engine process, as it takes seconds on big scans.
    """
    from amrst import pipeline
    from amrst.io.checks import refuse_same_points

    pair = [clouds[role] for role in ROLES if role in clouds]
    try:
        refuse_same_points(pair, [c.name or "scan" for c in pair])
    except InvalidInput as exc:
        raise SameScans(str(exc)) from None
    return _both(pipeline.prepare_scan, clouds, params, reporter)


def skeletonise_pair(
    analyses: dict, params: Any, reporter: Reporter
) -> tuple[dict, float]:
    """Skeleton and key points of both scans."""
    from amrst import pipeline

    return _both(pipeline.skeletonise_scan, analyses, params, reporter)


def match_pair(
    analyses: dict, params: Any, reporter: Reporter, manual: tuple = ()
) -> tuple[Any, float]:
    """Similar-tetrahedra candidates between the two key point sets; returns
    ``((MatchResult, manual candidates), seconds)``.

    ``manual`` holds ``(T_as_given, id, how)`` of the technician's poses: they are
    scored again with the new settings, so they stay in the list.
    """
    from amrst import pipeline

    start = time.perf_counter()
    result = pipeline.find_matches(
        analyses["target"], analyses["source"], params, reporter, threads=THREADS
    )
    rescored = tuple(
        _score_manual(analyses, T, cid, how, params) for T, cid, how in manual
    )
    return (result, rescored), time.perf_counter() - start


def _score_manual(analyses: dict, T: Any, cid: int, how: str, params: Any) -> Any:
    from amrst.review.manual import score_manual

    return score_manual(
        T, analyses["target"].xyz, analyses["source"].xyz, params.coarse, cid, how
    )


def score_manual_pair(
    analyses: dict, T: Any, cid: int, how: str, params: Any, reporter: Reporter
) -> tuple[Any, float]:
    """A manual pose as a candidate, verified like the automatic ones, and its
    :class:`PoseQuality` (the verdict judges a manual pose by it)."""
    start = time.perf_counter()
    reporter.progress(0.0, "Scoring the manual pose")
    cand = _score_manual(analyses, T, cid, how, params)
    reporter.check_cancelled()
    reporter.progress(0.5, "Measuring the manual pose where both scans saw the scene")
    quality = pose_quality(analyses, cand.T_target_source, params)
    reporter.progress(1.0, f"Manual pose: score {cand.score:.0%}")
    return (cand, quality), time.perf_counter() - start


def measure_tree_pair(
    analyses: dict, T_local: Any, params: Any, reporter: Reporter = NULL_REPORTER
) -> dict:
    """Height, DBH and crown of each scan and of both merged under ``T_local``, on
    the same bounded samples as ``amrst register`` (amrst.sampling.measure_pair), so
    the app and the command line give the same figures; stops at the reporter's
    cancel checks between the measurements."""
    from amrst.sampling import measure_pair
    from amrst.types import world_transform

    tgt, src = analyses["target"], analyses["source"]
    T_world = world_transform(T_local, tgt.cloud, src.cloud)
    return measure_pair(
        tgt.cloud,
        src.cloud,
        T_world,
        params.measure,
        reporter=reporter,
        trees=(tgt, src),
    )


def evaluate_coarse(
    analyses: dict, coarse: Any, params: Any, reporter: Reporter
) -> tuple[tuple[Any, Any, dict, PoseQuality], float]:
    """Measure the accepted coarse transform; ``(coarse, CloudMetrics, tree,
    PoseQuality)``."""
    from amrst import pipeline

    start = time.perf_counter()
    reporter.progress(0.0, "Measuring the coarse alignment")
    reporter.check_cancelled()
    metrics = pipeline.evaluate(
        analyses["target"],
        analyses["source"],
        coarse.T_target_source,
        params,
        threads=THREADS,
    )
    reporter.check_cancelled()
    reporter.progress(0.6, "Measuring the tree")
    tree = measure_tree_pair(analyses, coarse.T_target_source, params, reporter)
    reporter.check_cancelled()
    reporter.progress(0.8, "Measuring where both scans saw the scene")
    quality = pose_quality(analyses, coarse.T_target_source, params)
    reporter.progress(1.0, "Coarse alignment measured")
    return (coarse, metrics, tree, quality), time.perf_counter() - start


def refine_pair(
    analyses: dict, coarse: Any, params: Any, reporter: Reporter, matches: Any = None
) -> tuple[tuple[Any, Any, dict, PoseQuality, KeepDecision | None], float]:
    """Fine registration from the accepted ``coarse`` result, reusing a fit the
    match step already made for it (``matches``), then measured. From a manual
    candidate, Fine's result replaces the technician's pose only as
    :func:`amrst.review.manual_keep.keep_manual` decides. Returns ``(FineResult,
    CloudMetrics, tree measures, PoseQuality, the decision or None)``."""
    from amrst import pipeline
    from amrst.review.manual_keep import keep_manual
    from amrst.stages.candidates import Origin

    start = time.perf_counter()
    target, source = analyses["target"], analyses["source"]
    fine = pipeline.refine(
        target,
        source,
        coarse,
        params,
        SubReporter(reporter, 0, 0.9),
        matches,
        threads=THREADS,
    )
    decision = None
    candidate = getattr(coarse, "candidate", None)  # a plain transform has none
    if candidate is not None and candidate.origin == Origin.MANUAL:
        fine, decision = keep_manual(
            fine, coarse.T_target_source, target.xyz, source.xyz, params.coarse
        )
    reporter.check_cancelled()
    reporter.progress(0.9, "Measuring the fine alignment")
    metrics = pipeline.evaluate(
        analyses["target"],
        analyses["source"],
        fine.T_target_source,
        params,
        threads=THREADS,
    )
    reporter.check_cancelled()
    reporter.progress(0.95, "Measuring the tree")
    tree = measure_tree_pair(analyses, fine.T_target_source, params, reporter)
    reporter.check_cancelled()
    reporter.progress(0.97, "Measuring where both scans saw the scene")
    quality = pose_quality(analyses, fine.T_target_source, params)
    reporter.progress(1.0, "Fine registration done")
    return (fine, metrics, tree, quality, decision), time.perf_counter() - start


def pose_quality(analyses: dict, T_local: Any, params: Any) -> PoseQuality:
    """Overlap distances, strength per axis and stem slices of ``T_local`` (local
    frames), as ``amrst register`` measures them."""
    from amrst.pipeline.refine import pose_quality as measure

    return measure(analyses["target"], analyses["source"], T_local, params)


def export_pair(out_dir: Path, kwargs: dict, reporter: Reporter) -> tuple[list, float]:
    """Write the chosen outputs with ``amrst.results.export.export_registration``."""
    from amrst.results import export

    start = time.perf_counter()
    reporter.progress(0.0, f"Writing to {out_dir}")
    reporter.check_cancelled()
    paths = export.export_registration(out_dir, **kwargs)
    reporter.progress(1.0, f"Wrote {len(paths)} files")
    return list(paths), time.perf_counter() - start


def clip_tree_to(
    plot: Path, params: Any, out: Path, reporter: Reporter
) -> tuple[Path, int]:
    """Clip a tree from a plot file and write it to ``out``, or beside it as
    ``NAME_2.laz``... when ``out`` exists (an earlier clip is never replaced).

    Returns the file written and its number of points.
    """
    from amrst import io
    from amrst.clip import clip_tree

    result = clip_tree(plot, params, reporter)
    reporter.check_cancelled()
    out.parent.mkdir(parents=True, exist_ok=True)
    k, free = 1, out
    while True:  # the name is taken at once (O_EXCL): no other writer gets it too
        try:
            os.close(os.open(free, os.O_CREAT | os.O_EXCL | os.O_WRONLY))
            break
        except FileExistsError:
            k += 1
            free = out.with_name(f"{out.stem}_{k}{out.suffix}")
    try:
        io.write(free, result.cloud)  # atomic: replaces the empty file taken
    except BaseException:
        free.unlink(missing_ok=True)
        raise
    return free, len(result.cloud)


def read_truth(path: Path) -> np.ndarray:
    """The (4, 4) ``T_target_source`` of a truth JSON; ValueError says what is wrong.

    The same reader and checks as ``amrst register --truth`` (amrst.io.truth).
    """
    from amrst.errors import InvalidInput
    from amrst.io.truth import read_truth as read

    try:
        return read(path)
    except InvalidInput as exc:
        raise ValueError(str(exc)) from exc
