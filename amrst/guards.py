"""What the compiled libraries accept, checked before every call into them.

small_gicp, KISS-Matcher and Open3D do not raise on some inputs: they end the process
(a segmentation fault). small_gicp's KD-tree and GICP die on an empty cloud;
KISS-Matcher dies when either cloud yields no feature point (every point without
neighbours); their voxel grids pack 21 bits a key axis, so a point more than
``2**20`` voxels from the origin is dropped with a warning on stderr and a cloud
spanning more than the grid holds loses its far points silently. Open3D raises a
RuntimeError on voxel grids whose keys overflow. The functions here turn each such
input into a one-line :class:`~amrst.errors.InvalidInput`, or into "no result" where
that is the library's honest answer, before the library sees it.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from amrst.errors import InvalidInput

#: small_gicp's and KISS-Matcher's voxel keys: 21 bits an axis, offset by 2**20, so a
#: key holds ``-2**20 .. 2**20 - 1`` voxels about the origin.
GRID_HALF_VOXELS = 1 << 20

#: KISS-Matcher's normal estimate needs this many points within its normal radius
#: (``minimum_num_valid_`` of its FasterPFH), and a feature point as many neighbours
#: with a valid normal.
_KISS_MIN_NEIGHBOURS = 3

#: Feature points each cloud must show before KISS-Matcher is called. One on each
#: side keeps it alive; the margin covers the difference between its one point per
#: voxel and ours.
KISS_MIN_FEATURE_POINTS = 10

#: How messages name the two clouds of a pair.
TARGET, SOURCE = "the target scan", "the source scan"


def require_points(xyz: np.ndarray, what: str, at_least: int = 1) -> np.ndarray:
    """Return ``xyz`` as a (N, 3) float64 array of finite points, at least ``at_least``.

    Parameters
    ----------
    xyz : (N, 3) array_like
    what : str
        Names the cloud in the message, e.g. ``"the source scan"``.
    at_least : int
        Fewest points the caller's library accepts.

    Raises
    ------
    InvalidInput
        Fewer points, or a NaN/inf coordinate.
    """
    pts = np.asarray(xyz, dtype=np.float64)
    if pts.ndim != 2 or pts.shape[1] != 3:
        raise InvalidInput(
            f"{what} must be an (N, 3) array of points; got {pts.shape}."
        )
    if len(pts) < at_least:
        raise InvalidInput(
            f"{what} has {len(pts)} point(s) where at least {at_least} are needed: "
            "give a scan with more points (check the clip region and the filters)."
        )
    if not np.isfinite(pts).all():
        raise InvalidInput(
            f"{what} holds NaN or infinite coordinates: drop those points first."
        )
    return pts


def into_grid(
    xyz: np.ndarray, voxel_m: float, what: str
) -> tuple[np.ndarray, np.ndarray]:
    """Bring points within a 21-bit-a-key voxel grid about the origin.

    Points already within the grid are returned as they are (so a library's result
    does not change); otherwise they are moved by the centre of their bounding box,
    in float64, and the caller moves the result back by ``shift``.

    Parameters
    ----------
    xyz : (N, 3) float64, finite, not empty
    voxel_m : float
        The library's voxel size.
    what : str
        Names the cloud in the message.

    Returns
    -------
    points : (N, 3) float64
        ``xyz - shift``.
    shift : (3,) float64

    Raises
    ------
    InvalidInput
        The cloud spans more than the grid holds.
    """
    limit = (GRID_HALF_VOXELS - 2) * voxel_m
    lo, hi = xyz.min(axis=0), xyz.max(axis=0)
    if -limit < lo.min() and hi.max() < limit:
        return xyz, np.zeros(3)
    span = float((hi - lo).max())
    if span >= 2 * limit:
        raise InvalidInput(
            f"{what} spans {span:.3g} m: at {voxel_m:g} m voxels the matcher's grid "
            f"holds at most {2 * limit:.3g} m. Clip the scan to the tree (amrst "
            "clip) or remove its far outliers."
        )
    shift = (lo + hi) / 2
    return xyz - shift, shift


def feature_points(xyz: np.ndarray, voxel_m: float, radius_m: float) -> int:
    """Count the points of a one-per-voxel thinning with a normal KISS-Matcher can fit.

    A point counts when at least ``_KISS_MIN_NEIGHBOURS`` thinned points (itself
    included) lie within ``radius_m`` of it, as KISS-Matcher's FasterPFH requires.
    ``xyz`` must lie within the grid (:func:`into_grid`), so each key packs into one
    int64 as the library packs it.
    """
    keys = np.floor(xyz / voxel_m).astype(np.int64) + GRID_HALF_VOXELS
    code = (keys[:, 0] << 42) | (keys[:, 1] << 21) | keys[:, 2]
    thinned = xyz[np.sort(np.unique(code, return_index=True)[1])]
    counts = cKDTree(thinned).query_ball_point(thinned, radius_m, return_length=True)
    return int(np.count_nonzero(np.asarray(counts) >= _KISS_MIN_NEIGHBOURS))


@dataclass(frozen=True, slots=True)
class ShiftedPair:
    """Two clouds moved into a library's voxel grid, and the shifts that undo it."""

    target: np.ndarray  # (N, 3) float64
    source: np.ndarray  # (M, 3) float64
    target_shift: np.ndarray  # (3,) float64
    source_shift: np.ndarray  # (3,) float64

    def shift(self, T: np.ndarray) -> np.ndarray:
        """Return the (4, 4) pose between the moved clouds, from theirs as given."""
        T_shifted = np.array(T, dtype=np.float64)
        T_shifted[:3, 3] += T_shifted[:3, :3] @ self.source_shift - self.target_shift
        return T_shifted

    def unshift(self, T_shifted: np.ndarray) -> np.ndarray:
        """Return the (4, 4) pose between the clouds as given, from the moved ones'."""
        T = np.array(T_shifted, dtype=np.float64)
        T[:3, 3] += self.target_shift - T[:3, :3] @ self.source_shift
        return T


def grid_pair(
    target_xyz: np.ndarray, source_xyz: np.ndarray, voxel_m: float
) -> ShiftedPair:
    """Check two clouds and move each into a 21-bit-a-key voxel grid (small_gicp's).

    Raises
    ------
    InvalidInput
        An empty cloud, NaN/inf coordinates, a voxel size that is not > 0, or a span
        the grid cannot hold.
    """
    if not (np.isfinite(voxel_m) and voxel_m > 0):
        raise InvalidInput(f"The voxel size must be > 0 m; got {voxel_m}.")
    tgt, t_shift = into_grid(require_points(target_xyz, TARGET), voxel_m, TARGET)
    src, s_shift = into_grid(require_points(source_xyz, SOURCE), voxel_m, SOURCE)
    return ShiftedPair(tgt, src, t_shift, s_shift)


def kiss_pair(
    target_xyz: np.ndarray,
    source_xyz: np.ndarray,
    voxel_m: float,
    normal_radius_m: float,
) -> ShiftedPair | None:
    """Prepare two clouds for KISS-Matcher, or None when it could find no feature.

    Parameters
    ----------
    target_xyz, source_xyz : (N, 3), (M, 3) array_like
    voxel_m : float
        KISS-Matcher's voxel size.
    normal_radius_m : float
        Its normal radius (``KISSMatcherConfig.normal_radius``).

    Returns
    -------
    ShiftedPair or None
        None when either cloud has fewer than ``KISS_MIN_FEATURE_POINTS`` points with
        enough neighbours for a feature: KISS-Matcher would end the process there,
        and no pose is the honest answer.

    Raises
    ------
    InvalidInput
        As :func:`grid_pair`.
    """
    pair = grid_pair(target_xyz, source_xyz, voxel_m)
    for pts in (pair.target, pair.source):
        if feature_points(pts, voxel_m, normal_radius_m) < KISS_MIN_FEATURE_POINTS:
            return None
    return pair


def open3d_points(xyz: np.ndarray, voxel_m: float, what: str) -> np.ndarray:
    """Check points for Open3D's voxel down-sampling and KD-tree searches.

    Open3D raises on a voxel grid whose integer keys overflow ("voxel_size is too
    small") and on infinite coordinates; refused here with what to do.

    Returns
    -------
    (N, 3) float64
    """
    pts = require_points(xyz, what)
    span = float(np.ptp(pts, axis=0).max())
    # Open3D's bound: the span plus one voxel within INT_MAX voxels (a margin of 2).
    if span >= (np.iinfo(np.int32).max - 2) * voxel_m:
        raise InvalidInput(
            f"{what} spans {span:.3g} m, too wide for {voxel_m:g} m voxels: clip the "
            "scan to the tree (amrst clip) or remove its far outliers."
        )
    return pts
