"""A stored result as the session's own: a campaign tree opens without registering.

:meth:`StoredResultMixin.load_stored` reads the link's two scans (the one load job)
and then puts the stored result in place of the computed steps: one candidate (the
stored pose), the accepted coarse result and the fine result at that pose, the stored
metrics, tree measures, parameters and verdict. Match, Accept coarse and Fine then
read as done, so the overlay shows the stored pose at once and no step runs.

The usual workflow goes on from there: Export writes the stored pose; Fine refines it
(separating the scans first, without matching again); a manual pose or a new Match
adds candidates as for any pair. The stored verdict stands until a step replaces the
stored fine result. A mixin of :class:`~amrst_gui.session.Session`; no widgets.
"""

from __future__ import annotations

import logging
import math
from typing import TYPE_CHECKING, Any

import numpy as np

from amrst_gui import steps
from amrst_gui.results import ResultsMixin
from amrst_gui.step_jobs import StepJobsMixin

if TYPE_CHECKING:
    from collections.abc import Callable
    from pathlib import Path

    from amrst.campaign.stored import StoredLinkResult
    from amrst.measure import TreeMeasures
    from amrst.pipeline import MatchResult
    from amrst.review.verdict import Verdict
    from amrst.stages.fine import FineResult
    from amrst.types import Cloud

log = logging.getLogger("amrst_gui.session")

#: The id of the stored pose among the candidates (no match produces negative ids).
STORED_ID = -1
STORED_METHOD = "stored by the campaign batch"


class StoredResultMixin(StepJobsMixin, ResultsMixin):
    """Loading a stored link result into the session (a campaign tree)."""

    if TYPE_CHECKING:
        params_changed: Any
        truth_loaded: Any
        _truth_path: Path | None

        def _start_load(self, paths: dict[str, Path]) -> None: ...

    def _reset_results(self) -> None:
        super()._reset_results()
        self._stored: StoredLinkResult | None = None
        self._stored_matches: MatchResult | None = None
        self._stored_fine: FineResult | None = None

    # ------------------------------------------------------------ public
    def load_stored(
        self, target: str | Path, source: str | Path, stored: StoredLinkResult | None
    ) -> None:
        """Read both scans (a worker job), then show ``stored`` as their result.

        ``stored`` None loads the scans alone (a link with no stored pose).
        """
        from pathlib import Path

        self._pending_stored = stored
        self._start_load({"target": Path(target), "source": Path(source)})
        if self.runner.running_step != "load":  # refused: nothing pending
            self._pending_stored = None

    @property
    def stored(self) -> StoredLinkResult | None:
        """The stored result shown, until a step replaces its fine result."""
        return self._stored if self._fine is self._stored_fine else None

    @property
    def verdict(self) -> Verdict | None:
        """The stored verdict while the stored result stands, else the judged one."""
        stored = self.stored
        if stored is not None and self._stored_fine is not None:
            from amrst.review.verdict import Verdict

            v = stored.verdict
            return Verdict(
                str(v.get("status", "needs review")),
                str(v.get("reason", "")),
                str(v.get("next_step", "")),
            )
        return super().verdict

    def _stored_stands(self) -> bool:
        """True while the candidates are the stored pose's (no Match ran since)."""
        return (
            self._stored is not None and self.review.automatic is self._stored_matches
        )

    def plan(self, step: str) -> list[str]:
        """As for any pair, but from a stored pose Accept coarse and Fine only
        separate first: the stored candidate needs no skeleton or match."""
        if step not in ("coarse", "fine") or not self._stored_stands():
            return super().plan(step)
        fresh = self.is_done("separate") and not self.is_stale("separate")
        chain = [] if fresh else ["separate"]
        if step == "coarse" or not self.is_done("coarse") or self.is_stale("coarse"):
            chain.append("coarse")
        if step == "fine":
            chain.append("fine")
        return chain

    def _clear_after(self, step: str) -> None:
        # The stored pose and its candidate do not depend on the app's analyses.
        if step in ("separate", "skeleton") and self._stored_stands():
            return
        super()._clear_after(step)

    # ---------------------------------------------------------- internals
    def _apply_load(self, result: dict[str, Cloud]) -> Callable[[], None]:
        emit_loaded = super()._apply_load(result)
        stored = getattr(self, "_pending_stored", None)
        self._pending_stored = None
        if stored is None or self.cloud("target") is None:
            return emit_loaded
        emit_stored = self._apply_stored(stored)

        def emit() -> None:
            emit_loaded()
            emit_stored()

        return emit

    def _apply_stored(self, stored: StoredLinkResult) -> Callable[[], None]:
        from amrst.params import params_from_dict
        from amrst.pipeline import MatchResult
        from amrst.stages.candidates import Candidate, CoarseResult, Origin
        from amrst.stages.fine import FineResult
        from amrst.stages.match import TetraMatches

        params = self._params
        if stored.params:
            from amrst.errors import AmrstError

            try:
                params = params_from_dict(stored.params)
            except AmrstError as exc:  # keep the current parameters
                log.warning("%s: its params.json is not used: %s", stored.label, exc)
        same_params = steps.values_equal(params, self._params)
        self._params = params
        T = self.local(np.asarray(stored.T_world, float))
        try:
            origin = Origin(stored.origin)
        except ValueError:
            origin = Origin.TETRAHEDRA
        score = 0.0 if math.isnan(stored.score) else float(stored.score)
        candidate = Candidate(
            id=STORED_ID,
            rank=1,
            score=score,
            raw_score=score,
            support=0,
            volume_m3=math.nan,
            edge_error=math.nan,
            svd_residual_m=math.nan,
            target_idx=np.zeros(4, np.int64),
            source_idx=np.zeros(4, np.int64),
            T_match=T,
            T_target_source=T,
            polished=True,
            explanation=f"Stored result of the campaign batch ({stored.label})",
            origin=origin,
        )
        source = self.cloud("source")
        # On the GUI thread: the centre (for "same solution" tests) from every n-th
        # point, at most about 100,000, so that a big scan does not stall it.
        centre = (
            source.xyz[:: max(1, len(source.xyz) // 100_000)].mean(axis=0)
            if source is not None
            else np.zeros(3)
        )
        self.review.automatic = MatchResult(
            TetraMatches.empty(), (candidate,), 0, {}, np.asarray(centre)
        )
        confidence = 0.0 if math.isnan(stored.confidence) else stored.confidence
        coarse = CoarseResult(
            candidate,
            T,
            confidence,
            0.0,
            str(stored.verdict.get("reason", "")),
            stored.verified,
        )
        # A pair tree's metrics.json keeps what its ICP reported; a link of more
        # scans has the joint refinement's pose, no ICP of its own.
        icp = stored.metrics_fine or {}
        fine = FineResult(
            T,
            f"{icp['method']} ({STORED_METHOD})" if "method" in icp else STORED_METHOD,
            bool(icp.get("converged", True)),
            int(icp.get("iterations", 0)),
            float(icp.get("fitness", math.nan)),
            float(icp.get("inlier_rmse_m", math.nan)),
            math.nan,
        )
        self._accepted, self._fine = coarse, fine
        # Already on disk: switching trees never asks to discard it.
        self._exported_result = fine
        self.review.selected = STORED_ID
        self.review.link_review.accepted_pose = T
        for stage, values in (
            ("coarse", stored.metrics_coarse),
            ("fine", stored.metrics_fine),
        ):
            metrics = _cloud_metrics(values)
            if metrics is not None:
                self._metrics[stage] = metrics
        self._tree["fine"] = {
            name: m
            for name, d in stored.tree.items()
            if (m := _tree_measures(d)) is not None
        }
        for step in ("match", "coarse", "fine"):
            self._step_params[step] = params
        self._stored = stored
        self._stored_matches, self._stored_fine = self.review.automatic, fine
        truth = None if stored.T_truth is None else np.asarray(stored.T_truth, float)
        if truth is not None:  # the tree's truth file, for this link
            self._truth, self._truth_path = truth, None
        log.info(
            "Showing the stored result of %s: %s (no step ran).",
            stored.label,
            stored.verdict.get("status", ""),
        )

        def emit() -> None:
            # Not coarse_accepted: every view drawn on it draws again on
            # fine_finished (the fine result is the stored pose too), and each
            # redraw costs a switch between trees time.
            if not same_params:  # the Parameters dock rebuilds on it
                self.params_changed.emit(params)
            if truth is not None:
                self.truth_loaded.emit(truth)
            self.matches_changed.emit()
            self.fine_finished.emit(fine)

        return emit


def _cloud_metrics(values: dict[str, Any] | None) -> Any:
    from dataclasses import fields

    from amrst.stages.metrics import CloudMetrics

    if not values:
        return None
    names = [f.name for f in fields(CloudMetrics)]
    if any(n not in values for n in names):
        return None
    return CloudMetrics(**{n: values[n] for n in names})


def _tree_measures(d: dict[str, Any]) -> TreeMeasures | None:
    """TreeMeasures from their ``as_dict`` form (None when it is not one)."""
    from amrst.measure import TreeMeasures
    from amrst.measure.stem import StemCircle

    def num(key: str) -> float:
        value = d.get(key)
        return math.nan if value is None else float(value)

    if "height_m" not in d:
        return None
    stem = None
    if d.get("stem_x_m") is not None and not math.isnan(num("dbh_m")):
        stem = StemCircle(
            centre_xy=(num("stem_x_m"), num("stem_y_m")),
            radius_m=num("dbh_m") / 2,
            rmse_m=num("stem_rmse_m"),
            n_points=int(d.get("stem_points") or 0),
            arc_deg=num("stem_arc_deg"),
        )
    return TreeMeasures(
        n_points=int(d.get("n_points") or 0),
        base_z=num("base_z_m"),
        height_m=num("height_m"),
        dbh_m=num("dbh_m"),
        stem=stem,
        crown_area_m2=num("crown_area_m2"),
        crown_width_m=num("crown_width_m"),
        note=str(d.get("note", "")),
    )
