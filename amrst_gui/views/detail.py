"""The point actors of one view at its levels of detail (see ``lod``).

Each PointsLayer comes with its arrays at every level (``scene_jobs.prepare``:
all displayed points, every 2nd, 4th, ...). A level's VTK point set and actor are
made (on the GUI thread) only the first time it is shown, and exactly one level of
each layer is visible. Level ``k``
means the same for every layer (every ``2**k``-th point), so layers kept from an
earlier scene and new ones halve together.
"""

from __future__ import annotations

import re
from typing import Any

import numpy as np

from amrst_gui.views.lod import MIN_LEVEL_POINTS
from amrst_gui.views.scene import shown_text

_LEVEL = "__lod"  # actor name suffix of level k >= 1: "points__lod2"
_SHOWN = re.compile(r"showing (?:all )?[\d,]+ (?:of ([\d,]+) )?points")


class PointLevels:
    """Point layers of a plotter, each drawn at one level of detail."""

    def __init__(self, plotter) -> None:
        self.plotter = plotter
        self._sets: dict[str, tuple[tuple[np.ndarray, np.ndarray], ...]] = {}
        self._styles: dict[str, float] = {}  # point size per layer
        self._actors: dict[str, dict[int, Any]] = {}
        self.level = 0  # the level shown

    def set_layer(
        self,
        name: str,
        sets: tuple[tuple[np.ndarray, np.ndarray], ...],
        point_size: float,
    ) -> None:
        """Replace layer ``name``'s levels, ``(xyz, rgb)`` each; drawn at the next
        :meth:`show` (nothing is made for a level never shown)."""
        self.remove(name)
        self._sets[name] = sets
        self._styles[name] = point_size
        self._actors[name] = {}

    def remove(self, name: str) -> None:
        for k in self._actors.pop(name, {}):
            self.plotter.remove_actor(_actor_name(name, k), render=False)
        self._sets.pop(name, None)
        self._styles.pop(name, None)

    def names(self) -> list[str]:
        return list(self._sets)

    def levels(self) -> tuple[int, ...]:
        """Points drawn in all at each level (most first), down to the first
        level under twice ``lod.MIN_LEVEL_POINTS``."""
        if not self._sets:
            return ()
        depth = max(len(s) for s in self._sets.values())
        out: list[int] = []
        for k in range(depth):
            out.append(sum(len(s[min(k, len(s) - 1)][0]) for s in self._sets.values()))
            if out[-1] < 2 * MIN_LEVEL_POINTS:
                break
        return tuple(out)

    def show(self, level: int) -> None:
        """Draw every layer at ``level`` (clamped to what each has)."""
        self.level = max(0, level)
        for name in self._sets:
            self._show(name)

    def drawn(self) -> int:
        """Points of the visible actors."""
        return sum(len(self._sets[name][self._k(name)][0]) for name in self._sets)

    def _k(self, name: str) -> int:
        return min(self.level, len(self._sets[name]) - 1)

    def _show(self, name: str) -> None:
        k = self._k(name)
        actors = self._actors[name]
        if k not in actors:
            actors[k] = self.plotter.add_mesh(
                point_set(*self._sets[name][k]),
                scalars="rgb",
                rgb=True,
                style="points",
                point_size=self._styles[name],
                name=_actor_name(name, k),
                reset_camera=False,
                render=False,
                pickable=False,
            )
        for i, actor in actors.items():
            actor.SetVisibility(i == k)


def point_set(xyz: np.ndarray, rgb: np.ndarray) -> Any:
    """A pyvista point set of ``xyz`` (N, 3) coloured ``rgb`` (N, 3) uint8."""
    import pyvista as pv

    poly = pv.PolyData(np.ascontiguousarray(xyz, np.float32))
    poly["rgb"] = np.ascontiguousarray(rgb, np.uint8)
    return poly


def _actor_name(name: str, k: int) -> str:
    return name if k == 0 else f"{name}{_LEVEL}{k}"


def with_shown(text: str, shown: int) -> str:
    """A caption with its "showing N of M points" line saying ``shown`` points."""
    m = _SHOWN.search(text)
    if m is None:
        return text
    total = int((m.group(1) or re.sub(r"\D", "", m.group(0))).replace(",", ""))
    new = shown_text(min(shown, total), total)
    # shown_text may add " (fewer while the view moves)": keep the rest as it was.
    end = m.end()
    rest = text[end:]
    suffix = " (fewer while the view moves)"
    if rest.startswith(suffix):
        rest = rest[len(suffix) :]
    return text[: m.start()] + new + rest
