"""Build what the views draw from the session's results. Pure numpy, no Qt.

Clouds are decimated here for display only (``MAX_DISPLAY_POINTS`` per view);
every computation in the engine uses all points. The builders read ``session``
through its public names only, so a ``scene_jobs.Snapshot`` of it works the same
in a worker thread; everything they compute is bounded by the display size.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from amrst.results.report_images import SOURCE_RGB, TARGET_RGB
from amrst_gui.views.layers import (
    Layer,
    LinesLayer,
    PointsLayer,
    Ref,
    Scene,
    SpheresLayer,
    TextLayer,
)

MAX_DISPLAY_POINTS = 200_000
# Points drawn per view while the camera moves (rotate, pan, zoom), at most: few
# enough for a smooth orbit with software OpenGL.
MOVING_POINTS = 30_000

WOOD_RGB = (139, 90, 43)  # brown, as in the paper's figures
LEAF_RGB = (70, 170, 60)  # green
KIND_RGB = {"root": (255, 255, 255), "branch": (255, 150, 30), "end": (200, 210, 235)}
# One colour per tetrahedron vertex, the same in both views (vertex i <-> vertex i).
MATCH_RGB = np.array(
    [(230, 25, 75), (255, 225, 25), (240, 50, 230), (70, 240, 240)], np.uint8
)
TETRA_EDGES = np.array([(0, 1), (0, 2), (0, 3), (1, 2), (1, 3), (2, 3)])
COLOUR_MODES = ("height", "intensity", "wood", "scene")
REGISTRATION_STAGES = ("before", "coarse", "fine", "manual")
# Distance colouring: 0 cm dark blue ... DISTANCE_CLIP_M and beyond yellow/red.
DISTANCE_CLIP_M = 0.10


def distance_rgb(d: np.ndarray) -> np.ndarray:
    """(N, 3) uint8 colours of distances (m), turbo from 0 to DISTANCE_CLIP_M."""
    from matplotlib import colormaps

    # No neighbour within reach comes as inf (or NaN): the far end of the scale.
    d = np.nan_to_num(np.asarray(d, float), nan=DISTANCE_CLIP_M, posinf=DISTANCE_CLIP_M)
    t = np.clip(d / DISTANCE_CLIP_M, 0, 1)
    return (colormaps["turbo"](t)[:, :3] * 255).astype(np.uint8)


@dataclass(frozen=True)
class ViewOptions:
    """Display choices of one scan view (never used by the engine)."""

    show_points: bool = True
    colour: str = "height"  # one of COLOUR_MODES
    show_skeleton: bool = True
    show_keypoints: bool = True
    show_match: bool = True
    max_points: int = MAX_DISPLAY_POINTS


def display_index(n: int, max_points: int) -> slice:
    """Which of ``n`` points to draw: all, or an even stride down to ``max_points``."""
    step = max(1, -(-n // max(1, max_points)))
    return slice(None, None, step)


def height_rgb(xyz: np.ndarray, span_m: float | None = None) -> np.ndarray:
    """(N, 3) uint8 colours by height above the lowest point (viridis).

    ``span_m`` is the height the scale's top colour stands for (default: this
    cloud's own height range); two views given the same span show the same height
    above their lowest point in the same colour.
    """
    from matplotlib import colormaps

    z = xyz[:, 2]
    lo = z.min() if len(z) else 0.0
    span = span_m if span_m is not None else (z.max() - lo if len(z) else 1.0)
    t = np.clip((z - lo) / max(span, 1e-9), 0, 1)
    return (colormaps["viridis"](t)[:, :3] * 255).astype(np.uint8)


def shared_height_span(clouds) -> float | None:
    """The larger height range (m) of the given clouds (None when there is none)."""
    from amrst.sampling import strided

    # Every rebuild of either view asks: a sample is as good and costs no full pass.
    spans = [
        float(np.ptp(strided(c.xyz, 200_000)[:, 2]))
        for c in clouds
        if c is not None and len(c)
    ]
    return max(spans) if spans else None


def intensity_rgb(values: np.ndarray) -> np.ndarray:
    """(N, 3) uint8 grey levels from intensity, stretched between percentiles 2-98."""
    v = np.asarray(values, dtype=np.float64)
    lo, hi = np.percentile(v, [2, 98]) if len(v) else (0.0, 1.0)
    grey = 60 + 195 * np.clip((v - lo) / max(hi - lo, 1e-12), 0, 1)
    return np.repeat(grey.astype(np.uint8)[:, None], 3, axis=1)


def _marker_radius(xyz: np.ndarray) -> float:
    if len(xyz) == 0:
        return 0.05
    extent = np.ptp(xyz[:: max(1, len(xyz) // 5000)], axis=0)
    return float(max(np.linalg.norm(extent) * 0.008, 0.01))


def shown_text(shown: int, total: int) -> str:
    """The caption of how many points a view draws, e.g. "showing 200,000 of
    10,000,000 points (fewer while the view moves)"."""
    moving = " (fewer while the view moves)" if shown > MOVING_POINTS else ""
    if shown >= total:
        return f"showing all {total:,} points{moving}"
    return f"showing {shown:,} of {total:,} points{moving}"


def _title(session, role: str, cloud, options: ViewOptions, shown: int) -> str:
    label = "Target (reference)" if role == "target" else "Source (moved)"
    path = session.path(role)
    name = path.name if path else cloud.name
    lines = [f"{label}: {name}, {len(cloud):,} points"]
    if options.show_points:
        lines.append(shown_text(shown, len(cloud)))
    an = session.analysis(role)
    if an is not None:
        wood = float(np.mean(an.is_wood)) if len(an.is_wood) else 0.0
        text = f"wood {wood:.0%} of {len(an.is_wood):,} processed points"
        if options.colour == "wood":
            text += " (brown wood, green leaves)"
        lines.append(text)
        if options.colour == "scene" and an.scene is not None:
            lines.append(
                f"{an.scene.message} (green tree, brown ground, blue other, "
                "grey cut off)"
            )
        if an.skeleton is not None and an.keypoints is not None:
            n_nodes, n_kp = len(an.skeleton.nodes), len(an.keypoints.xyz)
            lines.append(
                f"{n_nodes} skeleton nodes; {n_kp} key points "
                "(white root, orange branch, pale end)"
            )
    cand = session.selected_match
    if cand is not None:
        state = "rejected" if cand.id in session.rejected else "candidate"
        lines.append(f"match #{cand.rank} ({state}, score {cand.score:.2f})")
    return "\n".join(lines)


def build_scan_scene(session, role: str, options: ViewOptions) -> Scene:
    """Layers of one scan view: points, skeleton, key points, the selected match."""
    cloud = session.cloud(role)
    if cloud is None:
        label = "Target (reference)" if role == "target" else "Source"
        text = f"{label}: no scan yet.\nOpen one (File menu) or drop a file here."
        return Scene(frame_key=(role, None), layers=(TextLayer("title", text),))
    an = session.analysis(role)
    layers: list = []
    shown = 0
    if options.show_points:
        both = (session.cloud("target"), session.cloud("source"))
        layers.append(_points_layer(cloud, an, options, both))
        shown = len(layers[-1].xyz)
    radius = _marker_radius(cloud.xyz)
    skel = None if an is None else an.skeleton
    kp = None if an is None else an.keypoints
    if options.show_skeleton and skel is not None and len(skel.edges):
        layers.append(
            LinesLayer(
                "skeleton",
                (Ref(skel),),
                np.asarray(skel.nodes, np.float32),
                np.asarray(skel.edges),
            )
        )
    if options.show_keypoints and kp is not None and len(kp.xyz):
        rgb = np.array(
            [KIND_RGB.get(str(k), (200, 200, 200)) for k in kp.kind], np.uint8
        )
        layers.append(SpheresLayer("keypoints", (Ref(kp),), kp.xyz, rgb, radius))
    cand = session.selected_match
    # Trunk-search solutions have no tetrahedron to draw.
    if (
        options.show_match
        and cand is not None
        and kp is not None
        and len(cand.target_idx) == 4
    ):
        idx = np.asarray(cand.target_idx if role == "target" else cand.source_idx)
        verts = np.asarray(kp.xyz, np.float32)[idx]
        rejected = cand.id in session.rejected
        key = (Ref(kp), int(cand.id), rejected)
        # Big enough to spot in the whole tree, small enough not to hide a small
        # tetrahedron's edges.
        edges = np.linalg.norm(
            verts[TETRA_EDGES[:, 0]] - verts[TETRA_EDGES[:, 1]], axis=1
        )
        vertex_radius = max(min(radius * 2.2, 0.2 * float(edges.min())), radius)
        layers.append(
            SpheresLayer("match_vertices", key, verts, MATCH_RGB, vertex_radius)
        )
        colour = (120, 120, 120) if rejected else (255, 255, 255)
        layers.append(LinesLayer("match_edges", key, verts, TETRA_EDGES, colour, 4.0))
    layers.append(TextLayer("title", _title(session, role, cloud, options, shown)))
    sub = cloud.xyz[display_index(len(cloud), 5000)]
    return Scene(
        frame_key=(role, Ref(cloud)), layers=tuple(layers), center=sub.mean(axis=0)
    )


def _points_layer(cloud, an, options: ViewOptions, both=()) -> PointsLayer:
    mode = options.colour
    scene = None if an is None else an.scene
    if mode == "scene" and scene is not None and an.scene_pre is not None:
        # The scene layer: tree, ground, other (neighbours, shrubs), cut off.
        from amrst_gui.views.layers import scene_layer

        sl = display_index(len(an.scene_pre.xyz), options.max_points)
        layer = scene_layer(an.scene_pre.xyz[sl], scene.labels[sl], "points")
        return PointsLayer(
            "points", ("scene", Ref(an), options.max_points), layer.xyz, layer.rgb
        )
    if mode == "wood" and an is not None:
        sl = display_index(len(an.xyz), options.max_points)
        xyz = np.asarray(an.xyz[sl], np.float32)
        wood = np.asarray(an.is_wood[sl], bool)
        rgb = np.where(
            wood[:, None], np.array(WOOD_RGB, np.uint8), np.array(LEAF_RGB, np.uint8)
        ).astype(np.uint8)
        return PointsLayer("points", ("wood", Ref(an), options.max_points), xyz, rgb)
    sl = display_index(len(cloud), options.max_points)
    xyz = cloud.xyz[sl]
    intensity = cloud.intensity
    if mode == "intensity" and intensity is not None:
        rgb = intensity_rgb(intensity[sl])
    else:
        # Both views on one scale, so the same colour is the same height in both.
        mode = "height"
        rgb = height_rgb(xyz, shared_height_span(both))
        return PointsLayer(
            "points",
            (mode, Ref(cloud), *map(Ref, both), options.max_points),
            xyz.astype(np.float32),
            rgb,
        )
    return PointsLayer(
        "points", (mode, Ref(cloud), options.max_points), xyz.astype(np.float32), rgb
    )


def moved_local(T_target_source: np.ndarray, xyz: np.ndarray) -> np.ndarray:
    """Source local points (N, 3) mapped into the target's local frame.

    The session's transforms are between local frames (as the engine computes
    them), so georeferenced scans never form large world coordinates here.
    """
    return xyz @ T_target_source[:3, :3].T + T_target_source[:3, 3]


def previewed_candidate(session):
    """The selected row when the *After coarse* overlay previews it, else None.

    Selecting a candidate other than the one accepted (or proposed) shows its pose,
    as Accept coarse would take it; a rejected row is not offered.
    """
    chosen = session.selected_match
    if chosen is None or chosen.id in session.rejected:
        return None
    shown = session.accepted_coarse or session.coarse
    if shown is not None and shown.candidate.id == chosen.id:
        return None
    return chosen


def registration_transform(session, stage: str) -> tuple[np.ndarray | None, str]:
    """The T_target_source shown for ``stage`` and a caption describing it."""
    if stage == "before":
        # As scanned: the identity in world coordinates, in local terms.
        return session.local(np.eye(4)), "Before registration (source as scanned)"
    if stage == "coarse":
        return _coarse_transform(session)
    if stage == "manual":
        T = session.manual_preview
        if T is not None:
            return T, "Manual pose (preview: point pairs and nudge, Manual dock)"
        return None, "No manual pose yet: pick point pairs or nudge (Manual dock)."
    fine = session.fine
    if fine is not None:
        return fine.T_target_source, f"After fine registration ({fine.method})"
    return None, "No fine registration yet: accept a coarse solution, then run Fine."


def shown_coarse(session) -> tuple[np.ndarray, int, str] | None:
    """The coarse pose the views show: ``(T_target_source, candidate rank, how)``,
    ``how`` being "selected" (a row previewed), "accepted" or "proposed" (what
    Accept coarse would take); None before matching or with every row rejected."""
    chosen = previewed_candidate(session)
    if chosen is not None:
        return np.asarray(chosen.T_target_source), int(chosen.rank), "selected"
    for how, coarse in (
        ("accepted", session.accepted_coarse),
        ("proposed", session.coarse),
    ):
        if coarse is not None:
            return np.asarray(coarse.T_target_source), int(coarse.candidate.rank), how
    return None


def _coarse_transform(session) -> tuple[np.ndarray | None, str]:
    """The *After coarse* overlay's pose (:func:`shown_coarse`) and its caption."""
    shown = shown_coarse(session)
    if shown is None:
        return None, f"No coarse solution yet. {session.coarse_message}"
    T, rank, how = shown
    return T, {
        "selected": f"Candidate #{rank}, selected, not accepted "
        "(Accept coarse takes it)",
        "accepted": "After coarse registration (accepted)",
        "proposed": "After coarse registration (proposed, not accepted)",
    }[how]


# Grey of the points only one scan saw: neither right nor wrong, so not coloured.
ONE_SCAN_RGB = (95, 95, 100)


def overlap_colours(
    t_xyz: np.ndarray, s_xyz: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Distances and colours of both scans' points where both saw the scene.

    A point counts when the overlap's voxel (``amrst.review.overlap``) it lies in
    holds points of both scans; the others are grey and left out of the distances
    (a stem's far side, ground behind a neighbour). Returns ``(target distances,
    target colours, source distances, source colours)``, distances of overlap
    points only.
    """
    from amrst.review.overlap import OVERLAP_VOXEL_M
    from amrst.review.quality import nn_distances
    from amrst.stages.voxels import voxel_grid

    code = voxel_grid(np.vstack([t_xyz, s_xyz]).astype(float), OVERLAP_VOXEL_M)[1]
    c_t, c_s = code[: len(t_xyz)], code[len(t_xyz) :]
    out: list[np.ndarray] = []
    for xyz, other, own, theirs in ((t_xyz, s_xyz, c_t, c_s), (s_xyz, t_xyz, c_s, c_t)):
        both = np.isin(own, theirs)
        d = nn_distances(xyz[both], other, 1.0)
        rgb = np.tile(np.array(ONE_SCAN_RGB, np.uint8), (len(xyz), 1))
        rgb[both] = distance_rgb(d)
        out += [d, rgb]
    return out[0], out[1], out[2], out[3]


def build_registration_scene(
    session, stage: str, max_points: int = MAX_DISPLAY_POINTS, colour: str = "scans"
) -> Scene:
    """Target and moved source overlaid in two colours, or coloured by the distance
    of each point to the other scan (``colour="distance"``)."""
    target, source = session.cloud("target"), session.cloud("source")
    if target is None or source is None:
        text = "Registration: open a target and a source scan."
        return Scene(
            frame_key=("registration", None), layers=(TextLayer("title", text),)
        )
    T, caption = registration_transform(session, stage)
    half = max(1, max_points // 2)
    t_xyz = target.xyz[display_index(len(target), half)].astype(np.float32)
    layers: list[Layer] = [
        PointsLayer(
            "target_points",
            ("target", Ref(target), half),
            t_xyz,
            np.tile(np.array(TARGET_RGB, np.uint8), (len(t_xyz), 1)),
        )
    ]
    legend = "amber: target (reference)   blue: source"
    distances = np.zeros(0)
    if T is not None:
        s_xyz = moved_local(T, source.xyz[display_index(len(source), half)]).astype(
            np.float32
        )
        key = ("source", Ref(source), half, T.tobytes(), colour)
        rgb = np.tile(np.array(SOURCE_RGB, np.uint8), (len(s_xyz), 1))
        if colour == "distance":
            d_t, rgb_t, d_s, rgb = overlap_colours(t_xyz, s_xyz)
            layers[0] = PointsLayer(
                "target_points",
                ("target", Ref(target), half, T.tobytes(), colour),
                t_xyz,
                rgb_t,
            )
            distances = np.concatenate([d_s, d_t])
            legend = (
                "colour: distance to the other scan where both saw the scene "
                "(blue 0 cm ... red 10 cm and more); grey: seen by one scan only"
            )
        layers.append(PointsLayer("source_points", key, s_xyz, rgb))
    shown = shown_text(
        sum(len(ly.xyz) for ly in layers if isinstance(ly, PointsLayer)),
        len(target) + (len(source) if T is not None else 0),
    )
    layers.append(TextLayer("title", f"{caption}\n{legend}\n{shown}"))
    return Scene(
        frame_key=("registration", Ref(target)),
        layers=tuple(layers),
        center=t_xyz.mean(axis=0) if len(t_xyz) else np.zeros(3),
        extra={"distances": distances},
    )
