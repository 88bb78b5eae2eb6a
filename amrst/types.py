"""Core data types: a point cloud with attributes and a georeferencing offset, and transforms.

Coordinates are float64 *local* coordinates plus a float64 ``offset`` (as LAS does), so
georeferenced clouds (x = 500000, y = 5000000) keep millimetres everywhere. Never float32.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from types import MappingProxyType
from typing import TYPE_CHECKING, Any, cast

import numpy as np

from amrst.errors import InvalidInput

if TYPE_CHECKING:
    from collections.abc import Mapping

Transform = np.ndarray  # (4, 4) float64 rigid transform, e.g. T_target_source

#: Coordinates beyond this (m) are invalid like NaN: no Earth coordinate, not even
#: geocentric (ECEF, about 6.4e6 m), comes near it. The readers drop such rows; a
#: Cloud refuses them, so no compiled library ever sees them.
MAX_COORD_M = 1e9


def _frozen_array(a: np.ndarray) -> np.ndarray:
    a = np.ascontiguousarray(a)
    a.setflags(write=False)
    return a


@dataclass(frozen=True, eq=False)
class Cloud:
    """A point cloud: local coordinates, an offset, and per-point attributes.

    Parameters
    ----------
    xyz : (N, 3) float64
        Local coordinates in metres; world coordinates are ``xyz + offset``.
    offset : (3,) float64
        Georeferencing offset in metres (zeros for local data).
    attributes : mapping of str to (N, ...) arrays
        Per-point fields kept end to end: ``intensity``, ``red``/``green``/``blue``,
        ``return_number``, ``number_of_returns``, ``classification``, extra dimensions.
    name : str
        A short label (usually the file name) for messages and the GUI.
    meta : mapping
        Format details worth keeping on write (e.g. LAS point format, scales).
    """

    xyz: np.ndarray
    offset: np.ndarray = field(default_factory=lambda: np.zeros(3))
    attributes: Mapping[str, np.ndarray] = field(default_factory=dict)
    name: str = ""
    meta: Mapping[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        xyz = np.asarray(self.xyz, dtype=np.float64)
        if xyz.ndim != 2 or xyz.shape[1] != 3:
            raise InvalidInput(
                f"Point array must have shape (N, 3); got {xyz.shape}. Give one row "
                "of x, y, z per point."
            )
        try:
            offset = np.asarray(self.offset, dtype=np.float64).reshape(3)
        except (TypeError, ValueError) as exc:
            raise InvalidInput(
                f"Cloud offset must be 3 numbers (x, y, z in metres); got "
                f"{self.offset!r:.60}."
            ) from exc
        _check_coordinates(xyz)
        if not np.isfinite(offset).all():
            raise InvalidInput(
                f"Cloud offset {offset.tolist()} is not finite; give 3 finite numbers "
                "(x, y, z in metres, zeros for local data)."
            )
        attrs = {}
        for key, value in dict(self.attributes).items():
            arr = np.asarray(value)
            if arr.shape[:1] != (len(xyz),):
                raise InvalidInput(
                    f"Attribute '{key}' has {arr.shape[0] if arr.ndim else 0} values "
                    f"for {len(xyz)} points."
                )
            attrs[key] = _frozen_array(arr)
        object.__setattr__(self, "xyz", _frozen_array(xyz))
        object.__setattr__(self, "offset", _frozen_array(offset))
        object.__setattr__(self, "attributes", MappingProxyType(attrs))
        object.__setattr__(self, "meta", MappingProxyType(dict(self.meta)))

    def __len__(self) -> int:
        return int(self.xyz.shape[0])

    def __reduce__(self) -> tuple[Any, ...]:
        # Pickled as its fields (a mappingproxy does not pickle), for the scan
        # worker and the app's engine process; see _cloud_from_fields.
        attrs, meta = dict(self.attributes), dict(self.meta)
        return _cloud_from_fields, (self.xyz, self.offset, attrs, self.name, meta)

    @property
    def world_xyz(self) -> np.ndarray:
        """(N, 3) float64 world coordinates (``xyz + offset``)."""
        return cast("np.ndarray", self.xyz + self.offset)

    @property
    def intensity(self) -> np.ndarray | None:
        """(N,) float64 intensity, or None when the scan has none."""
        value = self.attributes.get("intensity")
        return None if value is None else np.asarray(value, dtype=np.float64)

    def select(self, index: np.ndarray) -> Cloud:
        """Return a new cloud of the points picked by a boolean mask or an index array."""
        return Cloud(
            self.xyz[index],
            self.offset,
            {k: v[index] for k, v in self.attributes.items()},
            self.name,
            self.meta,
        )

    def with_xyz(self, xyz: np.ndarray, offset: np.ndarray | None = None) -> Cloud:
        """Return a new cloud with the same attributes and new coordinates (same N)."""
        return Cloud(
            xyz,
            self.offset if offset is None else offset,
            self.attributes,
            self.name,
            self.meta,
        )


def _check_coordinates(xyz: np.ndarray) -> None:
    """Refuse NaN, inf, or local coordinates beyond ``MAX_COORD_M``.

    Such values make no sense for a scan, and the compiled libraries the stages call
    (voxel grids with integer keys, KD-trees) crash the process on them instead of
    raising. Each column's minimum and maximum carry any NaN, so two reductions a
    column check every value.
    """
    if not len(xyz):
        return
    for d in range(3):
        lo, hi = float(xyz[:, d].min()), float(xyz[:, d].max())
        if not (lo >= -MAX_COORD_M and hi <= MAX_COORD_M):  # False for NaN too
            worst = (
                "NaN/inf"
                if not np.isfinite([lo, hi]).all()
                else f"{max(-lo, hi):.3g} m"
            )
            raise InvalidInput(
                f"Point coordinates hold {worst} (axis {'xyz'[d]}): a scan's local "
                f"coordinates must be finite and within {MAX_COORD_M:.0e} m. Drop "
                "those points, or put a georeferencing shift in the cloud's offset."
            )


def _cloud_from_fields(
    xyz: np.ndarray,
    offset: np.ndarray,
    attributes: dict[str, np.ndarray],
    name: str,
    meta: dict[str, Any],
) -> Cloud:
    """Rebuild an unpickled :class:`Cloud` from its fields, checked when it was made.

    The arrays are kept as they arrive (the app's engine pipe names a big array it
    sent before and hands back that very array), made read-only as a Cloud's are.
    """
    cloud = object.__new__(Cloud)
    for arr in (xyz, offset, *attributes.values()):
        arr.flags.writeable = False
    fields = {"xyz": xyz, "offset": offset, "name": name}
    fields |= {
        "attributes": MappingProxyType(attributes),
        "meta": MappingProxyType(meta),
    }
    for key, value in fields.items():
        object.__setattr__(cloud, key, value)
    return cloud


def make_transform(R: np.ndarray, t: np.ndarray) -> Transform:
    """(4, 4) float64 transform from a (3, 3) rotation and a (3,) translation."""
    out = np.eye(4)
    out[:3, :3] = R
    out[:3, 3] = t
    return out


def apply_transform(T_b_a: Transform, xyz: np.ndarray) -> np.ndarray:
    """Map (N, 3) points from frame a to frame b with the (4, 4) ``T_b_a``."""
    return cast("np.ndarray", xyz @ T_b_a[:3, :3].T + T_b_a[:3, 3])


def invert_transform(T_b_a: Transform) -> Transform:
    """Invert a rigid (4, 4) transform exactly (no general matrix inverse)."""
    R = T_b_a[:3, :3]
    return make_transform(R.T, -R.T @ T_b_a[:3, 3])


def transform_cloud(
    T_target_source: Transform, source: Cloud, target_offset: np.ndarray | None = None
) -> Cloud:
    """Move a cloud by a world-frame transform, keeping millimetres at any offset.

    ``T_target_source`` maps source *world* coordinates into target world coordinates.
    The result is expressed relative to ``target_offset`` (default: the source offset)
    without ever forming large world coordinates in the arithmetic of the small parts.

    Parameters
    ----------
    T_target_source : (4, 4) float64
    source : Cloud
    target_offset : (3,) float64 or None

    Returns
    -------
    Cloud
        Same attributes, coordinates in the target frame.
    """
    R = T_target_source[:3, :3]
    t = T_target_source[:3, 3]
    new_offset = (
        source.offset if target_offset is None else np.asarray(target_offset, float)
    )
    # world_t = R (xyz + o_s) + t ; local_t = world_t - o_new = R xyz + (R o_s + t - o_new)
    shift = R @ source.offset + t - new_offset
    return source.with_xyz(source.xyz @ R.T + shift, new_offset)


def rotation_angle_deg(R: np.ndarray) -> float:
    """Angle of a (3, 3) rotation in degrees, accurate near 0 and 180 (via the quaternion)."""
    from scipy.spatial.transform import Rotation

    return float(np.degrees(Rotation.from_matrix(np.asarray(R, float)).magnitude()))


# Largest |R^T R - I| entry a rotation block may show: 1e-4 admits matrices printed
# with 6 decimals (error ~1e-6) and still refuses any real scale or shear.
RIGID_TOL = 1e-4


# Georeferenced scans can lie in frames kilometres apart, never farther than the Earth
# is wide; a larger translation is a typo or other units, and its squares overflow.
MAX_TRANSLATION_M = 1e8


def check_translation(T: np.ndarray, where: str) -> np.ndarray:
    """Return ``T``, checked to move no farther than two scans may lie apart.

    Raises InvalidInput beyond ``MAX_TRANSLATION_M``.
    """
    from amrst.errors import InvalidInput

    shift = float(np.abs(T[:3, 3]).max())
    if shift > MAX_TRANSLATION_M:
        raise InvalidInput(
            f"{where} moves the source by {shift:.3g} m, farther than any two scans "
            f"lie apart (limit {MAX_TRANSLATION_M:.0e} m). Check its units (metres) "
            "and layout (4x4 row-major, translation in the last column)."
        )
    return T


def check_rigid(T: Any, where: str) -> np.ndarray:
    """Check that ``T`` is a rigid 4x4 transform; return it as float64.

    Parameters
    ----------
    T : array_like
        The matrix as read (nested lists).
    where : str
        Names the matrix in the messages, e.g. ``"T_target_source in truth.json"``.

    Returns
    -------
    (4, 4) float64

    Raises
    ------
    InvalidInput
        Not numbers, not 4x4, NaN/inf entries, a last row other than [0, 0, 0, 1],
        or a 3x3 block that is not a rotation (scale, shear, reflection) within
        ``RIGID_TOL``.
    """
    need = (
        "It must be a rigid 4x4 transform: a rotation and a translation, row-major, "
        "with last row [0, 0, 0, 1]."
    )
    try:
        M = np.asarray(T, dtype=float)
    except (TypeError, ValueError) as exc:
        raise InvalidInput(
            f"{where} is not a matrix of numbers ({exc}). {need}"
        ) from exc
    problem = rigid_problem(M)
    if problem is not None:
        raise InvalidInput(f"{where} {problem}. {need}")
    return M


def rigid_problem(M: np.ndarray) -> str | None:
    """Say what keeps a float matrix from being a rigid 4x4 transform, or None.

    The text follows the matrix's name: "contains NaN/inf", "has last row ...".
    """
    if M.shape != (4, 4):
        return f"must be a 4x4 matrix, got shape {M.shape}"
    if not np.all(np.isfinite(M)):
        return "contains NaN/inf"
    if not np.allclose(M[3], [0.0, 0.0, 0.0, 1.0], rtol=0.0, atol=RIGID_TOL):
        return f"has last row {M[3].tolist()}"
    R = M[:3, :3]
    deviation = float(np.abs(R.T @ R - np.eye(3)).max())
    if deviation > RIGID_TOL:
        return (
            "has a 3x3 block that is not a rotation (R^T R differs from the identity "
            f"by up to {deviation:.3g}: a scale or a shear)"
        )
    det = float(np.linalg.det(R))
    if det <= 0:
        return (
            f"has a 3x3 block with determinant {det:.3g}: a reflection, not a rotation"
        )
    return None


def world_transform(T_local: Transform, target: Cloud, source: Cloud) -> Transform:
    """Convert a transform between the clouds' local frames into world coordinates."""
    return cast(
        "np.ndarray",
        make_transform(np.eye(3), target.offset)
        @ T_local
        @ make_transform(np.eye(3), -source.offset),
    )


def local_transform(T_world: Transform, target: Cloud, source: Cloud) -> Transform:
    """Inverse of world_transform: a world transform expressed between local frames."""
    return cast(
        "np.ndarray",
        make_transform(np.eye(3), -target.offset)
        @ T_world
        @ make_transform(np.eye(3), source.offset),
    )
