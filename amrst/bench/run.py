"""Run registration methods on cases, interleaved, and score them against the truth.

For each case (read once) every method runs in turn; with ``repeat`` > 1 the order of
the methods rotates from one repeat to the next, so no method always runs first (warm
caches) or last. Only the method call is timed: the clouds are already in memory, the
lazily imported libraries are loaded before the first run, and scoring happens
afterwards. The time is the method's own ``timings["total"]`` (the fitness it computes
for itself is left out); the whole call is kept as ``wall_s``. A method that raises is
recorded with its error text and the run goes on; so is a case that cannot be read
(a failed record per method, with the reason).
"""

from __future__ import annotations

import logging
import time
import traceback
from collections.abc import Mapping, Sequence
from dataclasses import asdict, dataclass, field
from typing import TYPE_CHECKING, Any, cast

import numpy as np

from amrst.baselines import METHODS
from amrst.baselines._common import Method, MethodResult, to_local
from amrst.bench.within import within_fractions
from amrst.errors import AmrstError, Cancelled, InvalidInput
from amrst.files.atomic import make_folder
from amrst.io.cases import Case, find_cases, read_case
from amrst.progress import NULL_REPORTER, Reporter
from amrst.stages.metrics import measure_clouds, truth_errors
from amrst.types import apply_transform

if TYPE_CHECKING:
    import os
    from pathlib import Path

logger = logging.getLogger(__name__)

DEFAULT_METHODS = tuple(METHODS)  # every baseline, amrst last
NAN = float("nan")


@dataclass(slots=True, kw_only=True)
class RunRecord:
    """One method on one case (one repeat): errors, paper metrics, times."""

    case: str
    method: str
    repeat: int
    success: bool = False
    rotation_error_deg: float = NAN
    translation_error_m: float = NAN
    gt_rmse_m: float = NAN
    rmse_m: float = NAN
    rmse_overlap_m: float = NAN
    hausdorff_m: float = NAN
    hausdorff_p95_m: float = NAN
    overlap_fraction: float = NAN
    # Share of source points within 2 / 4 cm of the target under the estimate and
    # under the truth: when an unregistered estimate matches or beats the truth here,
    # the scans cannot tell the two poses apart at that tolerance.
    within_2cm: float = NAN
    within_4cm: float = NAN
    truth_within_2cm: float = NAN
    truth_within_4cm: float = NAN
    time_s: float = NAN  # the method's own compute total (timings["total"])
    wall_s: float = NAN  # the whole call, including the method's self-evaluation
    fitness: float = NAN
    inlier_rmse_m: float = NAN
    iterations: int | None = None
    converged: bool | None = None
    n_target: int = 0
    n_source: int = 0
    timings: dict[str, float] = field(default_factory=dict)
    extra: dict[str, Any] = field(default_factory=dict)
    error: str = ""

    def as_dict(self) -> dict[str, Any]:
        """Plain dict for JSON."""
        return asdict(self)


@dataclass(frozen=True, slots=True)
class BenchResult:
    """What :func:`run_bench` did and wrote."""

    runs: list[RunRecord]
    cases: list[str]
    methods: list[str]
    out_dir: Path
    files: list[Path]
    meta: dict[str, Any]


def resolve_methods(
    methods: Sequence[str] | Mapping[str, Method] | None,
) -> dict[str, Method]:
    """Resolve method callables by name, looked up in ``amrst.baselines.METHODS``.

    Parameters
    ----------
    methods : sequence of str, mapping of str to Method, or None
        None means all of ``DEFAULT_METHODS``.

    Returns
    -------
    dict of str to Method

    Raises
    ------
    InvalidInput
        If a name is unknown.
    """
    from amrst.baselines import METHODS

    if methods is None:
        methods = DEFAULT_METHODS
    if isinstance(methods, Mapping):
        return dict(methods)
    unknown = [m for m in methods if m not in METHODS]
    if unknown:
        raise InvalidInput(
            f"Unknown method(s) {unknown}; choose from {sorted(METHODS)}."
        )
    return {m: METHODS[m] for m in methods}


def score(
    case: Case, method: str, repeat: int, result: MethodResult, wall_s: float
) -> RunRecord:
    """Compare a method's result with the case truth (paper metrics and truth errors).

    Parameters
    ----------
    case : Case
    method : str
    repeat : int
    result : MethodResult
    wall_s : float
        Wall time of the method call (s); used as ``time_s`` when the method
        reports no finite ``timings["total"]``.

    Returns
    -------
    RunRecord
    """
    origin = case.target.offset
    src = case.source.xyz + (case.source.offset - origin)
    T_est = to_local(np.asarray(result.T_target_source, dtype=float), origin)
    T_true = to_local(case.T_target_source, origin)
    errors = truth_errors(T_est, T_true, src)
    compute = float(result.timings.get("total", NAN))
    metrics = measure_clouds(case.target.xyz, apply_transform(T_est, src))
    (est_2, est_4), (true_2, true_4) = within_fractions(
        case.target.xyz, src, [T_est, T_true]
    )
    return RunRecord(
        case=case.name,
        method=method,
        repeat=repeat,
        success=bool(errors.registered()),
        **cast("dict[str, Any]", errors.as_dict()),
        **cast(
            "dict[str, Any]",
            {k: v for k, v in metrics.as_dict().items() if not k.startswith("n_")},
        ),
        within_2cm=est_2,
        within_4cm=est_4,
        truth_within_2cm=true_2,
        truth_within_4cm=true_4,
        time_s=compute if np.isfinite(compute) and compute >= 0 else wall_s,
        wall_s=wall_s,
        fitness=float(result.fitness),
        inlier_rmse_m=float(result.inlier_rmse_m),
        iterations=result.iterations,
        converged=result.converged,
        n_target=len(case.target),
        n_source=len(case.source),
        timings={str(k): float(v) for k, v in result.timings.items()},
        extra={
            k: v for k, v in result.extra.items() if isinstance(v, (int, float, str))
        },
    )


def run_one(case: Case, name: str, method: Method, repeat: int) -> RunRecord:
    """Run and score one method on one case; an exception becomes the record's error."""
    t0 = time.perf_counter()
    try:
        result = method(case.target, case.source)
    except Cancelled:
        raise
    except Exception as exc:  # one failing method must not stop the benchmark
        wall = time.perf_counter() - t0
        logger.debug("%s on %s failed:\n%s", name, case.name, traceback.format_exc())
        return RunRecord(
            case=case.name,
            method=name,
            repeat=repeat,
            time_s=wall,
            wall_s=wall,
            n_target=len(case.target),
            n_source=len(case.source),
            error=f"{type(exc).__name__}: {exc}",
        )
    wall = time.perf_counter() - t0
    try:
        return score(case, name, repeat, result, wall)
    except Exception as exc:  # e.g. a non-finite transform
        return RunRecord(
            case=case.name,
            method=name,
            repeat=repeat,
            time_s=wall,
            error=f"scoring: {exc}",
        )


def unreadable_case(
    name: str, reason: str, methods: Sequence[str], repeat: int
) -> list[RunRecord]:
    """Failed records, one per method and repeat, for a case that cannot be read.

    Parameters
    ----------
    name : str
        The case folder name.
    reason : str
        Why it cannot be read; kept in each record's ``error``.
    methods : sequence of str
    repeat : int

    Returns
    -------
    list of RunRecord
    """
    return [
        RunRecord(case=name, method=m, repeat=r, error=f"case not read: {reason}")
        for r in range(repeat)
        for m in methods
    ]


def no_cases_message(cases_dir: str | os.PathLike[str], pattern: str | None) -> str:
    """Say why no case folder was found: none there, or the pattern matched none."""
    if not pattern:
        return f"No case folders (with truth.json) under {cases_dir}."
    every = [p.name for p in find_cases(cases_dir)]
    if not every:
        return (
            f"No case folders (with truth.json) under {cases_dir}, so the case "
            f"pattern {pattern!r} matched nothing."
        )
    shown = ", ".join(every[:10]) + (", ..." if len(every) > 10 else "")
    return (
        f"The case pattern {pattern!r} matched nothing: none of the {len(every)} "
        f"case folder(s) under {cases_dir} ({shown}) has a matching name. Check "
        "the pattern (shell style, e.g. '*normal*')."
    )


def warm_up(names: Sequence[str]) -> None:
    """Import the libraries the methods load lazily, so no first call pays for it."""
    import scipy.spatial  # noqa: F401

    if any(n != "amrst" for n in names):
        import open3d  # noqa: F401
    if "amrst" in names:
        import amrst.pipeline  # noqa: F401


def run_bench(
    cases_dir: str | os.PathLike[str],
    methods: Sequence[str] | Mapping[str, Method] | None = None,
    out_dir: str | os.PathLike[str] = "bench_out",
    repeat: int = 1,
    reporter: Reporter = NULL_REPORTER,
    *,
    pattern: str | None = None,
    command: str = "",
    plots: bool = True,
) -> BenchResult:
    """Run every method on every case, write results, summary and plots to ``out_dir``.

    Parameters
    ----------
    cases_dir : path
        Folder of case folders (each with target.*, source.*, truth.json), or one
        case folder.
    methods : sequence of str, mapping of str to Method, or None
        Names from ``amrst.baselines.METHODS`` or callables by name; None runs all six.
    out_dir : path
        Created if missing; files are replaced atomically.
    repeat : int
        Runs of each method on each case; the method order rotates between repeats.
    reporter : Reporter
        Gets ``progress(fraction, "case i/n <case> | <method>")`` before each run and
        is asked ``check_cancelled()`` between runs.
    pattern : str or None
        Shell pattern on case folder names.
    command : str
        The command line, recorded in the summary.
    plots : bool
        Also write the PNG plots.

    Returns
    -------
    BenchResult

    Raises
    ------
    InvalidInput
        If there are no cases, an unknown method, or ``repeat`` < 1.
    Cancelled
        If the reporter asks to stop (results so far are written first).
    """
    from amrst.bench.report import machine_info, write_outputs

    if repeat < 1:
        raise InvalidInput("repeat must be at least 1.")
    chosen = resolve_methods(methods)
    names = list(chosen)
    folders = find_cases(cases_dir, pattern)
    if not folders:
        raise InvalidInput(no_cases_message(cases_dir, pattern))
    out = make_folder(out_dir, "output folder")
    meta = {
        **machine_info(),
        "command": command,
        "cases_dir": str(cases_dir),
        "methods": names,
        "repeat": repeat,
        "unreadable_cases": {},
    }
    warm_up(names)
    runs: list[RunRecord] = []
    case_names: list[str] = []
    total = len(folders) * len(names) * repeat
    started = time.perf_counter()
    try:
        for i, folder in enumerate(folders):
            reporter.check_cancelled()
            try:
                case = read_case(folder)
            except Exception as exc:  # one unreadable case must not stop the benchmark
                reason = (
                    str(exc)
                    if isinstance(exc, AmrstError)
                    else f"{type(exc).__name__}: {exc}"
                )
                logger.warning("Case %s skipped: %s", folder.name, reason)
                meta["unreadable_cases"][folder.name] = reason
                case_names.append(folder.name)
                runs += unreadable_case(folder.name, reason, names, repeat)
                write_outputs(out, runs, case_names, names, meta, final=False)
                continue
            case_names.append(case.name)
            for r in range(repeat):
                order = names[r % len(names) :] + names[: r % len(names)]
                for name in order:
                    reporter.check_cancelled()
                    reporter.progress(
                        len(runs) / total,
                        f"case {i + 1}/{len(folders)} {case.name} | {name}",
                    )
                    runs.append(run_one(case, name, chosen[name], r))
            # Results so far are on disk after every case (a long run can be stopped).
            write_outputs(out, runs, case_names, names, meta, final=False)
    finally:
        meta["wall_s"] = time.perf_counter() - started
        files = write_outputs(
            out, runs, case_names, names, meta, final=True, plots=plots
        )
    reporter.progress(1.0, "done")
    return BenchResult(runs, case_names, names, out, files, meta)
