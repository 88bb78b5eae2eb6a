"""What a 3D view draws: named layers of plain arrays. No Qt, no VTK.

A view turns each layer into one named actor. ``key`` says what the content is
made of (identities of the source arrays and the display options), so a view
redraws a layer only when its key changes: calling ``update_scene`` twice with
the same scene changes nothing.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np


@dataclass(frozen=True, eq=False)
class PointsLayer:
    """Points with one RGB colour each: xyz (N, 3) float32, rgb (N, 3) uint8."""

    name: str
    key: tuple
    xyz: np.ndarray
    rgb: np.ndarray
    point_size: float = 2.0


@dataclass(frozen=True, eq=False)
class LinesLayer:
    """Segments between nodes: nodes (K, 3) float32, edges (E, 2) int."""

    name: str
    key: tuple
    nodes: np.ndarray
    edges: np.ndarray
    color: tuple[int, int, int] = (235, 235, 235)
    width: float = 2.0


@dataclass(frozen=True, eq=False)
class SpheresLayer:
    """Spheres of one radius (m) at centres (M, 3), coloured by rgb (M, 3) uint8."""

    name: str
    key: tuple
    centers: np.ndarray
    rgb: np.ndarray
    radius: float


@dataclass(frozen=True, eq=False)
class TextLayer:
    """A caption in a corner of the view."""

    name: str
    text: str
    position: str = "upper_left"

    @property
    def key(self) -> tuple:
        return (self.text, self.position)


class Ref:
    """Compares by identity and keeps its object alive, for layer keys.

    ``id()`` alone could be reused by a new object once the old one is freed,
    and engine results (frozen dataclasses holding arrays) cannot use ``==``.
    """

    __slots__ = ("obj",)

    def __init__(self, obj: object) -> None:
        self.obj = obj

    def __eq__(self, other: object) -> bool:
        return isinstance(other, Ref) and other.obj is self.obj

    def __hash__(self) -> int:
        return id(self.obj)


Layer = PointsLayer | LinesLayer | SpheresLayer | TextLayer


@dataclass(frozen=True, eq=False)
class Scene:
    """Everything one view shows.

    frame_key : changes when the data shown is a different scan (new file, swap);
        the view then resets its camera. Layer changes keep the camera.
    center, up : where linked cameras aim, in this scene's coordinates.
    """

    frame_key: tuple
    layers: tuple[Layer, ...] = ()
    center: np.ndarray = field(default_factory=lambda: np.zeros(3))
    extra: dict = field(default_factory=dict)  # derived numbers panels show

    def names(self) -> set[str]:
        """The actor names of this scene."""
        return {layer.name for layer in self.layers}


# Scene labels (amrst.stages.scene: tree, ground, other, outside) as colours:
# the tree green, the ground earth brown, neighbours and shrubs blue, cut-off grey.
SCENE_COLOURS = np.array(
    [[60, 170, 75], [150, 110, 70], [70, 120, 220], [120, 120, 120]], dtype=np.uint8
)


def scene_layer(
    xyz: np.ndarray, labels: np.ndarray, name: str = "scene"
) -> PointsLayer:
    """Points coloured by their scene label (the scene layer).

    xyz (N, 3) are the preprocessed points the labels refer to
    (``ScanAnalysis.scene_pre.xyz``); labels (N,) the ``SceneResult.labels``.
    """
    labels = np.asarray(labels)
    if labels.shape != (len(xyz),):
        raise ValueError(f"{len(labels)} labels for {len(xyz)} points")
    rgb = SCENE_COLOURS[np.clip(labels, 0, len(SCENE_COLOURS) - 1)]
    return PointsLayer(
        name, (Ref(xyz), Ref(labels)), np.asarray(xyz, dtype=np.float32), rgb
    )
