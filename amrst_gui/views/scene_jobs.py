"""Build a view's scene off the GUI thread, then draw it on the GUI thread.

A pane asks ``SceneLoader.request(build, snapshot, n_points)``: ``build(snapshot)``
(a ``scene.build_*_scene``) picks and colours the displayed points, then
:func:`prepare` cuts each point layer's levels of detail (every displayed point,
then every 2nd, 4th, ... point: see ``lod``) into contiguous arrays and computes
the framing bounds. For a big scan this runs in a display job of
``workers.run_stage``: plain numpy, no VTK. The view makes its VTK objects from
those arrays on the GUI thread, in its turn among the app's draws (``pacing``). A
newer request drops an older one still running or waiting.
Small scans (under ``SYNC_POINTS``) are built at once on the GUI thread: a few
milliseconds, and the views show their result before the signal that caused it
returns.

The worker never reads the live session: :class:`Snapshot` copies the references
the builders need on the GUI thread (every result is a frozen engine object).
"""

from __future__ import annotations

import functools
import logging
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import numpy as np
from PySide6.QtCore import QObject, Signal

from amrst_gui.pacing import DRAWS
from amrst_gui.views.layers import PointsLayer, Scene

if TYPE_CHECKING:
    from collections.abc import Callable

    from amrst_gui.workers import StageJob

log = logging.getLogger("amrst_gui.views")

# Scans up to this many points are built on the GUI thread (a few ms).
SYNC_POINTS = 300_000
_ROLES = ("target", "source")


class Snapshot:
    """What the scene builders read from the session, fixed at one moment.

    Same names as the session's (``cloud(role)``, ``path(role)``,
    ``analysis(role)``, ``local(T)``, ``selected_match``, ``rejected``, ``coarse``,
    ``coarse_message``, ``accepted_coarse``, ``manual_preview``, ``fine``), so a
    builder takes either.
    """

    def __init__(self, session) -> None:
        self._clouds = {r: session.cloud(r) for r in _ROLES}
        self._paths = {r: session.path(r) for r in _ROLES}
        self._analyses = {r: session.analysis(r) for r in _ROLES}
        self.selected_match = session.selected_match
        self.rejected = session.rejected
        self.coarse = session.coarse
        self.coarse_message = session.coarse_message
        self.accepted_coarse = session.accepted_coarse
        self.manual_preview = session.manual_preview
        self.fine = session.fine

    def cloud(self, role: str) -> Any:
        return self._clouds[role]

    def path(self, role: str) -> Any:
        return self._paths[role]

    def analysis(self, role: str) -> Any:
        return self._analyses[role]

    def local(self, T_world: np.ndarray) -> np.ndarray:
        """A world T_target_source between the scans' local frames (the session's
        ``local``, on the snapshot's clouds)."""
        from amrst.types import local_transform

        return local_transform(T_world, self._clouds["target"], self._clouds["source"])

    def n_points(self, *roles: str) -> int:
        """Points in the clouds of ``roles`` (what a build may have to read)."""
        return sum(len(c) for r in roles if (c := self._clouds[r]) is not None)


@dataclass
class Prepared:
    """One scene's arrays, cut in the worker: ``sets[name]``, each PointsLayer's
    ``(xyz float32, rgb uint8)`` at every level of detail (every displayed point,
    then every 2nd, 4th, ... point: :func:`level_slices`), and ``bounds`` to frame."""

    sets: dict[str, tuple[tuple[np.ndarray, np.ndarray], ...]] = field(
        default_factory=dict
    )
    bounds: np.ndarray | None = None


# Levels of detail of a layer: every 2**k-th displayed point, down to this many.
MIN_SET_POINTS = 1_000


def level_slices(n: int, smallest: int = MIN_SET_POINTS) -> list[slice]:
    """The strides of a layer's levels: all ``n`` points, then every 2nd, 4th, ...
    while a level keeps at least ``smallest`` points. The same level index halves
    every layer of a view, whichever scene made it."""
    out = [slice(None)]
    step = 2
    while -(-n // step) >= smallest:
        out.append(slice(None, None, step))
        step *= 2
    return out


BOUNDS_SAMPLE = 50_000


def fit_bounds(xyz_list: list[np.ndarray]) -> np.ndarray | None:
    """Bounds to frame: the points' 0.5-99.5 percentiles, plus 5 % each side.

    A few stray points metres away (real scans have them) would otherwise push the
    tree into a corner of the view.
    """
    pts = [x for x in xyz_list if len(x)]
    if not pts:
        return None
    # An even sample of at most BOUNDS_SAMPLE points: the percentiles move by
    # millimetres only.
    total = sum(len(x) for x in pts)
    step = max(1, -(-total // BOUNDS_SAMPLE))
    xyz = np.concatenate([x[::step] for x in pts])
    lo, hi = np.percentile(xyz, [0.5, 99.5], axis=0)
    pad = 0.05 * (hi - lo)
    return np.column_stack([lo - pad, hi + pad]).ravel()


def prepare(scene: Scene) -> Prepared:
    """The arrays the view draws ``scene`` from: each PointsLayer's levels as
    contiguous float32 points and uint8 colours, and the bounds to frame."""
    points = [ly for ly in scene.layers if isinstance(ly, PointsLayer)]
    out = Prepared(bounds=fit_bounds([ly.xyz for ly in points]))
    for layer in points:
        out.sets[layer.name] = tuple(
            (
                np.ascontiguousarray(layer.xyz[sl], np.float32),
                np.ascontiguousarray(layer.rgb[sl], np.uint8),
            )
            for sl in level_slices(len(layer.xyz))
        )
    return out


def build_and_prepare(
    build: Callable[[Snapshot], Scene], snapshot: Snapshot, reporter
) -> tuple[Scene, Prepared]:
    """Worker function: the scene, then its arrays (cancel checked between)."""
    reporter.check_cancelled()
    scene = build(snapshot)
    reporter.check_cancelled()
    return scene, prepare(scene)


class SceneLoader(QObject):
    """Builds a view's scenes, the newest request only; ``view.update_scene`` draws.

    Emits ``drawn()`` after a scene built here was handed to the view (the GUI
    thread), and ``failed(message)`` when building one raised.
    """

    drawn = Signal()
    failed = Signal(str)

    def __init__(self, view, parent: QObject | None = None) -> None:
        super().__init__(parent or view)
        self.view = view
        self._job: StageJob | None = None

    @property
    def pending(self) -> bool:
        """True while a scene is being built in a worker or waits to be drawn."""
        return self._job is not None or DRAWS.waits(self, "scene")

    def request(
        self,
        build: Callable[[Snapshot], Scene],
        snapshot: Snapshot,
        n_points: int,
    ) -> None:
        """Build ``build(snapshot)`` and draw it; ``n_points`` is the input size."""
        from amrst_gui import workers

        self.drop()
        if n_points <= SYNC_POINTS:
            scene = build(snapshot)
            self.view.update_scene(scene, prepare(scene))
            self.drawn.emit()
            return
        job = workers.run_stage(
            build_and_prepare,
            build,
            snapshot,
            name="display",
            display=True,
            on_result=lambda out: self._apply(job, out),
            on_error=lambda exc: self._failed(job, exc),
        )
        self._job = job

    def drop(self) -> None:
        """Forget the scene being built (a newer one replaces it, or the view goes)."""
        DRAWS.drop(self, "scene")
        if self._job is not None:
            self._job.discard()
            self._job = None

    def _apply(self, job, out: tuple[Scene, Prepared]) -> None:
        if job is not self._job:
            return
        self._job = None
        DRAWS.later(self, "scene", functools.partial(self._draw, out))

    def _draw(self, out: tuple[Scene, Prepared]) -> None:
        if getattr(self.view, "_closed", False):
            return  # the window closed while the scene waited
        self.view.update_scene(*out)
        self.drawn.emit()

    def _failed(self, job, exc: BaseException) -> None:
        if job is not self._job:
            return
        self._job = None
        log.error(
            "Could not build the view: %s",
            getattr(exc, "__traceback_text__", repr(exc)),
        )
        self.failed.emit(f"The view could not be drawn: {type(exc).__name__}: {exc}")
