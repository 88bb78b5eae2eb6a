"""The registration report's pictures, drawn with matplotlib's Agg (no display, no Qt).

Four PNGs: the overlay (top and side views, target amber, source blue), the distance
colouring (each moved source point coloured by its distance to the target, in cm), the
distance histogram (both ways) and the stem slices with their fitted circles. The
command line uses them as they are; the app may pass its own screenshots instead.
"""

from __future__ import annotations

import io
from typing import TYPE_CHECKING

import numpy as np

from amrst.review.quality import nn_distances
from amrst.review.verdict import FAILED, TEXT_RGB
from amrst.sampling import random_rows

if TYPE_CHECKING:
    from collections.abc import Sequence

    from matplotlib.figure import Figure

    from amrst.review.quality import StemSlice

# Target amber, source blue, 0-255: the app draws the scans in these colours too.
TARGET_RGB = (240, 170, 40)
SOURCE_RGB = (60, 150, 255)
DISTANCE_CLIP_M = 0.10  # the colour scale ends here, as in the app
MAX_POINTS = 30_000  # per cloud and picture: enough to see, quick to draw


def _unit(rgb: tuple[int, int, int]) -> tuple[float, float, float]:
    """Return a 0-255 colour on matplotlib's 0-1 scale."""
    r, g, b = rgb
    return r / 255, g / 255, b / 255


_TARGET, _SOURCE = _unit(TARGET_RGB), _unit(SOURCE_RGB)


def png_bytes(fig: Figure, dpi: int = 100) -> bytes:
    """Render ``fig`` with Agg at ``dpi``; return the PNG."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg

    FigureCanvasAgg(fig)
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=dpi)
    return buf.getvalue()


def new_figure(width_in: float, height_in: float) -> Figure:
    """Return a bare Figure (constrained layout) of this size in inches.

    A bare Figure renders with Agg and leaves pyplot's global backend alone.
    """
    from matplotlib.figure import Figure

    return Figure(figsize=(width_in, height_in), layout="constrained")


def overlay_png(target_xyz: np.ndarray, moved_source_xyz: np.ndarray) -> bytes:
    """Top (x-y) and side (x-z, y-z) views of both scans in their colours."""
    fig = new_figure(11, 4.6)
    axes = fig.subplots(1, 3)
    t = random_rows(target_xyz, MAX_POINTS)
    s = random_rows(moved_source_xyz, MAX_POINTS, 1)
    for ax, (i, j, name) in zip(
        axes,
        ((0, 1, "Top (x-y)"), (0, 2, "Front (x-z)"), (1, 2, "Side (y-z)")),
        strict=True,
    ):
        ax.scatter(t[:, i], t[:, j], s=0.3, color=_TARGET, label="target", lw=0)
        ax.scatter(s[:, i], s[:, j], s=0.3, color=_SOURCE, label="source", lw=0)
        ax.set_aspect("equal", adjustable="datalim")
        ax.set_title(name)
        ax.set_xlabel("xyz"[i] + " (m)")
        ax.set_ylabel("xyz"[j] + " (m)")
    axes[0].legend(markerscale=20, loc="upper right", fontsize=8)
    return png_bytes(fig)


def distance_png(moved_source_xyz: np.ndarray, distances_m: np.ndarray) -> bytes:
    """Colour the moved source by its distance to the target (front and side)."""
    fig = new_figure(11, 4.6)
    axes = fig.subplots(1, 2)
    keep = np.isfinite(distances_m)
    xyz, d = moved_source_xyz[keep], distances_m[keep]
    idx = np.argsort(d)  # the far points are drawn last, on top
    idx = random_rows(idx, MAX_POINTS, 2)
    idx = idx[np.argsort(d[idx])]
    art = None
    for ax, (i, j, name) in zip(
        axes, ((0, 2, "Front (x-z)"), (1, 2, "Side (y-z)")), strict=True
    ):
        art = ax.scatter(
            xyz[idx, i],
            xyz[idx, j],
            c=np.minimum(d[idx], DISTANCE_CLIP_M) * 100,
            cmap="turbo",
            vmin=0,
            vmax=DISTANCE_CLIP_M * 100,
            s=0.5,
            lw=0,
        )
        ax.set_aspect("equal", adjustable="datalim")
        ax.set_title(f"Source coloured by distance to the target: {name}")
        ax.set_xlabel("xyz"[i] + " (m)")
        ax.set_ylabel("xyz"[j] + " (m)")
    if art is not None:
        bar = fig.colorbar(art, ax=list(axes), shrink=0.8)
        bar.set_label(f"distance (cm, {DISTANCE_CLIP_M * 100:.0f} and more at the top)")
    return png_bytes(fig)


def histogram_png(to_target_m: np.ndarray, to_source_m: np.ndarray) -> bytes:
    """Histogram of the nearest-neighbour distances both ways, in cm."""
    fig = new_figure(8, 3.2)
    ax = fig.subplots()
    bins = [float(b) for b in np.linspace(0, DISTANCE_CLIP_M * 100, 26)]
    for d, colour, name in (
        (to_target_m, _SOURCE, "source to target"),
        (to_source_m, _TARGET, "target to source"),
    ):
        d = d[np.isfinite(d)]
        ax.hist(
            np.minimum(d, DISTANCE_CLIP_M) * 100,
            bins=bins,
            color=colour,
            alpha=0.6,
            label=f"{name}: median {np.median(d) * 100:.1f} cm" if len(d) else name,
        )
    ax.set_xlabel(
        f"distance to the nearest point of the other scan (cm; the last bar holds "
        f"{DISTANCE_CLIP_M * 100:.0f} cm and more)"
    )
    ax.set_ylabel("points")
    ax.legend(fontsize=8)
    return png_bytes(fig)


def slices_png(slices: Sequence[StemSlice]) -> bytes:
    """One square per slice: both scans' points, their circles, and the caption."""
    import matplotlib.patches as mpatches

    n = max(len(slices), 1)
    fig = new_figure(3.6 * n, 4.2)
    axes = np.atleast_1d(fig.subplots(1, n))
    for ax, sl in zip(axes, slices, strict=False):
        circles = [c for c in (sl.target_circle, sl.source_circle) if c is not None]
        for xy, colour in ((sl.target_xy, _TARGET), (sl.source_xy, _SOURCE)):
            if len(xy):
                ax.scatter(xy[:, 0], xy[:, 1], s=2, color=colour, lw=0)
        for c, colour in (
            (sl.target_circle, _TARGET),
            (sl.source_circle, _SOURCE),
        ):
            if c is not None:
                ax.add_patch(
                    mpatches.Circle(c.centre_xy, c.radius_m, fill=False, color=colour)
                )
        if circles:
            cx, cy = circles[0].centre_xy
            half = max(max(c.radius_m for c in circles) * 1.8, 0.05)
            ax.set_xlim(cx - half, cx + half)
            ax.set_ylim(cy - half, cy + half)
        ax.set_aspect("equal")
        ax.tick_params(labelsize=7)
        first, second = sl.caption()
        ax.set_title(first, fontsize=10)
        note_colour = TEXT_RGB[FAILED] if sl.problem() else "black"
        ax.set_xlabel(_wrap(second, 40), fontsize=8, color=note_colour)
    return png_bytes(fig)


def _wrap(text: str, width: int) -> str:
    import textwrap

    return "\n".join(textwrap.wrap(text, width))


def render_all(
    target_xyz: np.ndarray,
    moved_source_xyz: np.ndarray,
    slices: Sequence[StemSlice],
) -> dict[str, bytes]:
    """Every picture of the report, by name (overlay, distance, histogram, slices)."""
    t = random_rows(target_xyz, MAX_POINTS)
    s = random_rows(moved_source_xyz, MAX_POINTS, 1)
    to_target = nn_distances(s, target_xyz)
    to_source = nn_distances(t, moved_source_xyz)
    return {
        "overlay": overlay_png(target_xyz, moved_source_xyz),
        "distance": distance_png(s, to_target),
        "histogram": histogram_png(to_target, to_source),
        "slices": slices_png(slices),
    }
