"""Read-only views of the session's results: derived values, never stored twice.

A mixin of the Session; it holds no Qt code and emits nothing.
"""

from __future__ import annotations

import dataclasses
from typing import TYPE_CHECKING, Any

from amrst_gui import jobs, steps

if TYPE_CHECKING:
    from pathlib import Path

    import numpy as np

    from amrst.measure import TreeMeasures
    from amrst.params import RegistrationParams
    from amrst.pipeline import MatchResult, ScanAnalysis
    from amrst.review.verdict import Verdict
    from amrst.stages.candidates import Candidate, CoarseResult
    from amrst.stages.fine import FineResult
    from amrst.stages.metrics import CloudMetrics, TruthErrors
    from amrst.types import Cloud
    from amrst_gui.review import Review

_TRUTH_SAMPLE = 20_000


class ResultsMixin:
    """Results and derived state of a :class:`~amrst_gui.session.Session`."""

    if TYPE_CHECKING:
        # Set by the host class, Session.__init__; declared here for mypy.
        _params: RegistrationParams
        _truth: np.ndarray | None
        review: Review

        def cloud(self, role: str) -> Cloud | None: ...
        def path(self, role: str) -> Path | None: ...
        def analysis(self, role: str) -> ScanAnalysis | None: ...
        def _reset_analyses(self) -> None: ...

    def _reset_results(self) -> None:
        self._reset_analyses()
        self.review.reset()
        self._accepted: CoarseResult | None = None
        self._fine: FineResult | None = None
        self._fine_note = ""  # from a manual pose: what Fine's check decided
        self._metrics: dict[str, CloudMetrics] = {}
        # stage -> {"target"|"source"|"merged": TreeMeasures}
        self._tree: dict[str, dict[str, TreeMeasures]] = {}
        self._timings: dict[str, float] = {
            k: v for k, v in getattr(self, "_timings", {}).items() if k == "load"
        }
        self._step_params: dict[str, RegistrationParams] = {}
        self._exported_result: CoarseResult | FineResult | None = None
        self._override: dict[str, str] | None = None

    def _clear_after(self, step: str) -> None:
        """Drop the results built on ``step``'s (each later step clears its own)."""
        for name in steps.later_steps(step):
            getattr(self, f"_clear_{name}")()  # step_jobs.py, per step
            self._step_params.pop(name, None)
            self._timings.pop(name, None)

    # ---------------------------------------------------------------- review
    @property
    def matches(self) -> tuple[Candidate, ...]:
        """Ranked candidates, manual poses first, then the automatic ones."""
        return self.review.matches

    @property
    def match_result(self) -> MatchResult | None:
        """The MatchResult with the manual candidates in front, or None."""
        return self.review.match_result

    @property
    def manual_candidates(self) -> tuple[Candidate, ...]:
        """The manual candidates (origin "manual"), newest first."""
        return self.review.manual_candidates

    @property
    def manual_labels(self) -> dict[int, str]:
        """How each manual candidate was made ("3 point pairs", "typed", ...), by id."""
        return self.review.manual_labels

    @property
    def rejected(self) -> frozenset[int]:
        """Ids of the candidates the user rejected."""
        return self.review.rejected

    @property
    def selected_match(self) -> Candidate | None:
        """The Candidate shown in the views, or None."""
        return self.review.selected_match

    @property
    def coarse(self) -> CoarseResult | None:
        """CoarseResult from the best candidate not rejected (None if none is left)."""
        return self.review.coarse

    @property
    def coarse_message(self) -> str:
        """Why the coarse solution is what it is (or why there is none)."""
        return self.review.coarse_message

    @property
    def verdict(self) -> Verdict | None:
        """The verdict of the current registration, or None before matching."""
        params = self._step_params.get("match") or self._params
        return self.review.verdict(self._accepted, self._fine, params)

    # ----------------------------------------------------------------- state
    @property
    def has_scans(self) -> bool:
        """True when both target and source are loaded."""
        return all(self.cloud(r) is not None for r in jobs.ROLES)

    @property
    def accepted_coarse(self) -> CoarseResult | None:
        """The CoarseResult the user accepted, or None."""
        return self._accepted

    @property
    def fine(self) -> FineResult | None:
        """The FineResult, or None."""
        return self._fine

    @property
    def fine_note(self) -> str:
        """From a manual pose: whether Fine's result was kept, and why ("" else)."""
        return self._fine_note if self._fine is not None else ""

    @property
    def metrics(self) -> dict[str, CloudMetrics]:
        """CloudMetrics by stage ("coarse", "fine")."""
        return dict(self._metrics)

    @property
    def tree(self) -> dict[str, TreeMeasures]:
        """TreeMeasures of "target", "source" and "merged" under the best result so far
        (fine if done, else the accepted coarse); empty before."""
        return dict(self._tree.get("fine") or self._tree.get("coarse") or {})

    @property
    def timings(self) -> dict[str, float]:
        """Seconds per step that ran."""
        return dict(self._timings)

    @property
    def has_unexported_result(self) -> bool:
        """True when a coarse or fine result exists that was not exported."""
        final = self._fine or self._accepted
        return final is not None and final is not self._exported_result

    @property
    def final_transform(self) -> np.ndarray | None:
        """The best T_target_source so far (local frames, as the engine works):
        fine if done, else the accepted coarse."""
        if self._fine is not None:
            return self._fine.T_target_source
        if self._accepted is not None:
            return self._accepted.T_target_source
        return None

    def world(self, T_local: np.ndarray) -> np.ndarray:
        """A local-frame T_target_source in world coordinates (export, truth)."""
        from amrst.types import world_transform

        return world_transform(T_local, *self._pair_clouds())

    def local(self, T_world: np.ndarray) -> np.ndarray:
        """A world T_target_source between the scans' local frames (the views)."""
        from amrst.types import local_transform

        return local_transform(T_world, *self._pair_clouds())

    def _pair_clouds(self) -> tuple[Cloud, Cloud]:
        target, source = self.cloud("target"), self.cloud("source")
        assert target is not None  # no transform before both scans are loaded
        assert source is not None
        return target, source

    @property
    def result_params(self) -> RegistrationParams:
        """The parameters the current result was computed with (else the current)."""
        used = self._step_params.get("fine" if self._fine is not None else "coarse")
        return used or self._params

    @property
    def export_override(self) -> dict[str, str] | None:
        """How the last export overrode a verdict that was not *registered*."""
        return None if self._override is None else dict(self._override)

    def is_done(self, step: str) -> bool:
        """True when the step's result exists (stale or not)."""
        done = getattr(self, f"_done_{step}", None)  # step_jobs.py, per step
        return bool(done()) if done is not None else False

    def is_stale(self, step: str) -> bool:
        """True when a result exists but was computed with other parameters."""
        if not self.is_done(step):
            return False
        used = self._step_params.get(step)
        if used is None:
            return True
        from amrst.stages.candidates import Origin

        groups = steps.groups_for(step)
        if step in ("match", "coarse") and any(
            c.origin == Origin.TRUNK for c in self.matches
        ):
            # Trunk-search solutions were refined and verified with the fine settings.
            groups = (*groups, "fine")
        for group in groups:
            if not steps.values_equal(
                getattr(used, group), getattr(self._params, group)
            ):
                return True
        if step in ("coarse", "fine"):
            current = self.coarse
            assert self._accepted is not None  # is_done(step) holds
            accepted = self._accepted.candidate
            if (
                current is None
                or accepted is None
                or current.candidate.id != accepted.id
            ):
                return True
        return step == "fine" and self.is_stale("coarse")

    def plan(self, step: str) -> list[str]:
        """Steps ``run_step(step)`` runs: the missing or stale ones, then ``step``."""
        out: list[str] = []
        for name in steps.STEPS[: steps.STEPS.index(step) + 1]:
            if out or name == step or not self.is_done(name) or self.is_stale(name):
                out.append(name)
        return out

    # --------------------------------------------------------- derived values
    def truth_errors(self) -> dict[str, TruthErrors]:
        """TruthErrors by stage ("coarse", "fine") when a truth file is loaded."""
        source = self.cloud("source")
        if self._truth is None or source is None:
            return {}
        from amrst.stages.metrics import truth_errors

        xyz = source.world_xyz[:: max(1, len(source) // _TRUTH_SAMPLE)]
        out = {}
        coarse = self._accepted or self.coarse
        if coarse is not None:
            out["coarse"] = truth_errors(
                self.world(coarse.T_target_source), self._truth, xyz
            )
        if self._fine is not None:
            out["fine"] = truth_errors(
                self.world(self._fine.T_target_source), self._truth, xyz
            )
        return out

    def export_arguments(self, cloud_format: str, parts=None) -> dict[str, Any]:
        """Keyword arguments of ``amrst.results.export.export_registration`` (but out_dir)."""
        T_final = self.final_transform
        # Session.export, the only caller, returns early while this is None.
        assert T_final is not None
        assert self._accepted is not None  # a final transform needs an accepted one
        from amrst import __version__
        from amrst.results.documents import ResultRecord, result_documents

        fine = self._fine
        verdict = self.verdict
        context = self._transform_context()
        target, source = self.cloud("target"), self.cloud("source")
        assert target is not None  # a result needs both scans
        assert source is not None
        # The one result layout of the CLI, the app and the benchmark.
        record = ResultRecord(
            # The engine works between local frames; the files hold world transforms.
            T_target_source=self.world(T_final),
            T_coarse=self.world(self._accepted.T_target_source),
            target_name=target.name,
            source_name=source.name,
            target_file=context["target_file"],
            source_file=context["source_file"],
            coarse=self._accepted,
            fine=fine,
            metrics_coarse=self._metrics["coarse"].as_dict()
            if "coarse" in self._metrics
            else None,
            metrics_fine=self._metrics["fine"].as_dict()
            if "fine" in self._metrics and fine is not None
            else None,
            truth=self.truth_errors(),
            tree=self.tree,
            timings_s=dict(self._timings),
            rejected_match_ids=tuple(sorted(int(i) for i in self.review.rejected)),
            verdict=None if verdict is None else verdict.as_dict(),
            override=None if self._override is None else dict(self._override),
            extra={k: context[k] for k in ("manual_pose",) if k in context},
            amrst_version=__version__,
        )
        kwargs: dict[str, Any] = {
            "target": target,
            "source": source,
            "T_target_source": record.T_target_source,
            # The parameters the result was computed with (export refuses stale ones).
            "params": self.result_params,
            "cloud_format": cloud_format,
            "documents": result_documents(record),
        }
        if parts is not None:
            kwargs["parts"] = tuple(parts)
        return kwargs

    def _transform_context(self) -> dict[str, Any]:
        coarse, fine = self._accepted, self._fine
        assert coarse is not None  # only exported results have a context
        extra: dict[str, Any] = {
            "target_file": str(self.path("target") or ""),
            "source_file": str(self.path("source") or ""),
            "stage": "fine" if fine is not None else "coarse",
            "coarse_confidence": float(coarse.confidence),
            "coarse_match_rank": None
            if coarse.candidate is None
            else int(coarse.candidate.rank),
            "coarse_origin": None
            if coarse.candidate is None
            else str(coarse.candidate.origin),
            "verified": bool(coarse.verified),
            "rejected_match_ids": sorted(int(i) for i in self.review.rejected),
        }
        verdict = self.verdict
        if verdict is not None:
            extra["verdict"] = verdict.as_dict()
        if self._override is not None:
            # A result that is not "registered" leaves only on purpose.
            extra["override"] = dict(self._override)
        if coarse.candidate is not None and coarse.candidate.origin == "manual":
            extra["manual_pose"] = {
                "how": self.review.manual_labels.get(int(coarse.candidate.id), ""),
                "T_target_source_as_given": self.world(
                    coarse.candidate.T_match
                ).tolist(),
            }
        if fine is not None:
            extra.update(
                fine_method=str(fine.method), fine_converged=bool(fine.converged)
            )
        return extra

    def metrics_report(self) -> dict[str, dict]:
        """Everything measured, as plain dicts for the export."""
        report: dict[str, dict] = {}
        for stage, m in self._metrics.items():
            report[stage] = dict(m.as_dict())
        if self._accepted is not None:
            c = self._accepted
            report.setdefault("coarse", {}).update(
                confidence=float(c.confidence),
                candidate_id=None if c.candidate is None else int(c.candidate.id),
                rejected_ids=sorted(int(i) for i in self.review.rejected),
            )
        if self._fine is not None:
            f = self._fine
            report.setdefault("fine", {}).update(
                converged=bool(f.converged),
                iterations=int(f.iterations),
                fitness=float(f.fitness),
                inlier_rmse_m=float(f.inlier_rmse_m),
                method=str(f.method),
            )
        for stage, err in self.truth_errors().items():
            report.setdefault(stage, {}).update(
                {f"truth_{k}": v for k, v in err.as_dict().items()}
            )
        if self.tree:
            report["tree"] = {name: m.as_dict() for name, m in self.tree.items()}
        report["timings_s"] = dict(self._timings)
        verdict = self.verdict
        if verdict is not None:
            report["verdict"] = verdict.as_dict()
        if self._override is not None:
            report["override"] = dict(self._override)
        return report

    def summary(self, step: str) -> str:
        """One line about a step's result, for the log."""
        line = getattr(self, f"_summary_{step}", None)  # step_jobs.py, per step
        return str(line()) if line is not None else ""

    # --------------------------------------------------------------- helpers
    def _name(self, role: str) -> str:
        path, cloud = self.path(role), self.cloud(role)
        return path.name if path else (cloud.name if cloud is not None else "-")

    def _groups(self) -> list[str]:
        return [f.name for f in dataclasses.fields(self._params)]

    def _params_text(self, step: str) -> str:
        if step not in steps.STEPS:
            return ""
        parts = []
        for group in steps.own_groups(step):
            values = getattr(self._params, group, None)
            if values is None:
                continue
            fields = ", ".join(
                f"{f.name}={getattr(values, f.name)}"
                for f in dataclasses.fields(values)
            )
            parts.append(f"{group}({fields})")
        return " with " + "; ".join(parts) if parts else ""

    def _hint(self, step: str) -> str:
        groups = steps.own_groups(step)
        if not groups:
            return ""
        return (
            f" (Try other '{', '.join(groups)}' values in the Parameters dock, "
            "or a preset, and run the step again.)"
        )
