"""Manual recovery: a pose from picked point pairs, a nudge, or a typed transform.

When automatic matching fails, the technician gives the pose by hand. The
result becomes a candidate like the others (origin ``"manual"``), polished and scored
by the same verification as the tetrahedron candidates, so its verdict means the same.
All transforms here are ``T_target_source`` between the scans' local frames.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from amrst.errors import InvalidInput
from amrst.geometry import kabsch, yaw_rotation
from amrst.types import Transform, check_rigid, check_translation

if TYPE_CHECKING:
    from amrst.stages.coarse import Candidate, CoarseParams

# Manual candidates get ids from here up, apart from the automatic ones.
MANUAL_ID_BASE = 1_000_000


@dataclass(frozen=True, slots=True)
class PairFit:
    """A transform fitted to point pairs, and how well each pair agrees with it.

    Attributes
    ----------
    T_target_source : (4, 4) float64
    residuals_m : (K,) float64
        Distance of each target point from its source point moved by the fit.
    levelled : bool
        True when only yaw and translation were fitted.
    """

    T_target_source: Transform
    residuals_m: np.ndarray
    levelled: bool

    @property
    def rmse_m(self) -> float:
        """RMS of the residuals (m)."""
        return float(np.sqrt(np.mean(self.residuals_m**2)))


def _pairs(
    target_pts: np.ndarray, source_pts: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    t = np.asarray(target_pts, float).reshape(-1, 3)
    s = np.asarray(source_pts, float).reshape(-1, 3)
    if len(t) != len(s):
        raise InvalidInput(
            f"{len(t)} target points but {len(s)} source points: pick the counterpart "
            "of every target point."
        )
    return t, s


def fit_rigid(target_pts: np.ndarray, source_pts: np.ndarray) -> Transform:
    """Least-squares rotation and translation mapping source onto target (Kabsch).

    Parameters
    ----------
    target_pts, source_pts : (K, 3) float64
        Corresponding points, K >= 3 and not all on one line.

    Returns
    -------
    (4, 4) float64
        ``T_target_source``.

    Raises
    ------
    InvalidInput
        Fewer than 3 pairs, or the points lie on a line.
    """
    t, s = _pairs(target_pts, source_pts)
    if len(t) < 3:
        raise InvalidInput(
            f"{len(t)} point pair(s): a full rotation needs 3 (or 2 with the levelled "
            "constraint)."
        )
    sv = np.linalg.svd(s - s.mean(axis=0), compute_uv=False)
    if sv[1] < 1e-3 * max(sv[0], 1e-12):
        raise InvalidInput(
            "The source points lie on a line, so the rotation about it is unknown: "
            "pick a pair off that line."
        )
    transforms, _ = kabsch(s[None], t[None])
    return np.asarray(transforms[0])


def fit_levelled(
    target_pts: np.ndarray,
    source_pts: np.ndarray,
    weights: np.ndarray | None = None,
) -> Transform:
    """Rotation about the vertical (z) axis and translation, for levelled scans.

    Parameters
    ----------
    target_pts, source_pts : (K, 3) float64
        Corresponding points, K >= 2, not all on one vertical line.
    weights : (K,) float64 or None
        How much each pair counts (positive; None: all alike).

    Returns
    -------
    (4, 4) float64
        ``T_target_source`` with a pure yaw rotation.

    Raises
    ------
    InvalidInput
        Fewer than 2 pairs, or no horizontal spread to fix the yaw.
    """
    t, s = _pairs(target_pts, source_pts)
    if len(t) < 2:
        raise InvalidInput(
            f"{len(t)} point pair(s): the levelled fit needs 2 (a full fit 3)."
        )
    w = np.ones(len(t)) if weights is None else np.asarray(weights, float)
    w = w / w.sum()
    tc, sc = w @ t, w @ s
    a, b = (s - sc)[:, :2], (t - tc)[:, :2]
    for points, scan in ((a, "source"), (b, "target")):
        if np.linalg.norm(points, axis=1).max() < 1e-3:
            raise InvalidInput(
                f"The {scan} points are on one vertical line, so the heading is "
                "unknown: pick points that are apart horizontally."
            )
    # Best yaw in closed form (2-D Procrustes): atan2(sum a x b, sum a . b).
    cross = np.sum(w * (a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0]))
    dot = np.sum(w * (a[:, 0] * b[:, 0] + a[:, 1] * b[:, 1]))
    R = yaw_rotation(np.arctan2(cross, dot))
    out = np.eye(4)
    out[:3, :3] = R
    out[:3, 3] = tc - R @ sc
    return out


def pair_residuals(
    T_target_source: Transform, target_pts: np.ndarray, source_pts: np.ndarray
) -> np.ndarray:
    """(K,) distance (m) between each target point and its moved source point."""
    t, s = _pairs(target_pts, source_pts)
    moved = s @ T_target_source[:3, :3].T + T_target_source[:3, 3]
    return np.asarray(np.linalg.norm(moved - t, axis=1))


#: How far a point picked by eye may miss the feature meant (m).
PICK_ERROR_M = 0.05
#: A turn about the vertical that such a miss swings by more than this is weak (deg).
WEAK_TURN_DEG = 5.0


def turn_swing(target_pts: np.ndarray) -> tuple[float, float]:
    """How firmly the pairs fix the turn about the vertical.

    The turn's lever is how far the picked points spread across the ground (from
    their middle); a pick that misses by :data:`PICK_ERROR_M` at that lever turns the
    pose by the returned angle. Two points on one stem, a few cm apart across the
    ground however far apart in height, fix almost no turn.

    Returns
    -------
    (float, float)
        The lever (m) and the swing (deg; 180 when the points stand on one vertical).
    """
    t = np.asarray(target_pts, float).reshape(-1, 3)
    if not len(t):
        return 0.0, 180.0
    lever = float(np.linalg.norm(t[:, :2] - t[:, :2].mean(axis=0), axis=1).max())
    if lever <= 0:
        return 0.0, 180.0
    return lever, float(np.degrees(np.arctan2(PICK_ERROR_M, lever)))


def weak_turn(target_pts: np.ndarray) -> str:
    """One sentence when the pairs hardly fix the turn (:func:`turn_swing`), else ""."""
    lever, swing = turn_swing(target_pts)
    if swing <= WEAK_TURN_DEG:
        return ""
    return (
        f"Weak turn: the points spread {lever:.2f} m across the ground, so a "
        f"{PICK_ERROR_M * 100:.0f} cm miss turns the pose {swing:.0f}°; add a pair "
        "far from the stem (a crown tip, a branch end)."
    )


#: Point pairs whose points lie this much farther apart (or nearer) in one scan than in
#: the other (RMS over every two rows, m) name different points.
PAIRS_APART_M = 1.0


def pairs_disagree(target_pts: np.ndarray, source_pts: np.ndarray) -> str:
    """One sentence when the pairs cannot be the same points in both scans, else "".

    A move of a scan keeps the distances between its points, however it turns or
    tilts; picks by eye change them by a miss, rows in another order or a pick on
    the wrong stem by far more.
    """
    t, s = _pairs(target_pts, source_pts)
    if len(t) < 2:
        return ""
    i, j = np.triu_indices(len(t), 1)
    dt = np.linalg.norm(t[i] - t[j], axis=1)
    ds = np.linalg.norm(s[i] - s[j], axis=1)
    off = np.abs(dt - ds)
    rms = float(np.sqrt(np.mean(off**2)))
    if not rms > PAIRS_APART_M:
        return ""
    w = int(np.argmax(off))
    return (
        f"name different points: rows {i[w] + 1} and {j[w] + 1} lie {dt[w]:.1f} m "
        f"apart in one scan and {ds[w]:.1f} m in the other ({rms:.1f} m RMS over "
        "every two rows); check that each row holds the same point in both scans"
    )


def fit_pairs(
    target_pts: np.ndarray, source_pts: np.ndarray, levelled: bool = False
) -> PairFit:
    """Fit point pairs: the full rigid fit from 3 pairs, yaw + translation from 2.

    With ``levelled`` the yaw fit is used whatever the number of pairs (scans that
    were levelled in the field differ only by a heading and a shift).

    Parameters
    ----------
    target_pts, source_pts : (K, 3) float64
    levelled : bool

    Returns
    -------
    PairFit

    Raises
    ------
    InvalidInput
        Too few pairs, or points that cannot fix the pose.
    """
    t, s = _pairs(target_pts, source_pts)
    use_levelled = levelled or len(t) == 2
    T = fit_levelled(t, s) if use_levelled else fit_rigid(t, s)
    return PairFit(T, pair_residuals(T, t, s), use_levelled)


def nudge(
    T_target_source: Transform,
    yaw_deg: float = 0.0,
    shift_m: tuple[float, float, float] = (0.0, 0.0, 0.0),
    pivot: np.ndarray | None = None,
) -> Transform:
    """Turn the moved source about a vertical axis through ``pivot``, then shift it.

    Parameters
    ----------
    T_target_source : (4, 4) float64
    yaw_deg : float
        Turn about the vertical, counter-clockwise seen from above (deg).
    shift_m : (3,) float
        Shift in the target frame (m).
    pivot : (3,) float64 or None
        A point of the target frame on the axis (default: the origin), e.g. the stem.

    Returns
    -------
    (4, 4) float64
    """
    p = np.zeros(3) if pivot is None else np.asarray(pivot, float)
    turn = np.eye(4)
    turn[:3, :3] = yaw_rotation(np.radians(yaw_deg))
    turn[:3, 3] = p - turn[:3, :3] @ p + np.asarray(shift_m, float)
    out: np.ndarray = turn @ np.asarray(T_target_source, float)
    return out


def parse_transform(text: str, where: str = "the transform") -> Transform:
    """Read a 4x4 ``T_target_source`` from JSON or text, as the export writes it.

    Accepts ``transform.json`` (a ``T_target_source`` key, or a bare 4x4 list) and
    ``transform.txt`` (four rows of four numbers; ``#`` comments and commas allowed).

    Parameters
    ----------
    text : str
    where : str
        Named in the error message.

    Returns
    -------
    (4, 4) float64

    Raises
    ------
    InvalidInput
        Not 4x4 numbers, or not a rigid transform.
    """
    stripped = text.strip()
    value: object
    if stripped.startswith(("{", "[")):
        try:
            value = json.loads(stripped)
        except json.JSONDecodeError as exc:
            raise InvalidInput(f"{where} is not valid JSON: {exc}") from None
        if isinstance(value, dict):
            if "T_target_source" not in value:
                raise InvalidInput(
                    f"{where} has no T_target_source entry (keys: "
                    f"{', '.join(map(str, value)) or 'none'})."
                )
            value = value["T_target_source"]
    else:
        rows = []
        for line in stripped.splitlines():
            line = line.split("#", 1)[0].replace(",", " ").strip()
            if line:
                try:
                    rows.append([float(v) for v in line.split()])
                except ValueError:
                    raise InvalidInput(
                        f"{where}: '{line}' is not a row of numbers."
                    ) from None
        if len(rows) == 3 and all(len(r) == 4 for r in rows):
            rows.append([0.0, 0.0, 0.0, 1.0])  # a 3x4 [R|t] is fine too
        value = rows
    try:
        arr = np.asarray(value, dtype=float)
    except (TypeError, ValueError):
        raise InvalidInput(f"{where} must hold 4 rows of 4 numbers.") from None
    if arr.shape != (4, 4):
        raise InvalidInput(
            f"{where} must hold 4 rows of 4 numbers, not shape {arr.shape}."
        )
    return check_translation(check_rigid(arr, where), where)


def tight_share(
    T_target_source: Transform,
    target_tree: object,
    sample: np.ndarray,
    dist_m: float,
) -> float:
    """Share of ``sample`` source points within ``dist_m`` of the target under a pose.

    The live score of the nudge (no polish): ``target_tree`` is a
    ``scipy.spatial.cKDTree`` on the target points, ``sample`` (n, 3) source points.
    """
    moved = sample @ T_target_source[:3, :3].T + T_target_source[:3, 3]
    d = target_tree.query(moved, distance_upper_bound=dist_m)[0]  # type: ignore[attr-defined]
    return float(np.mean(d < dist_m)) if len(d) else 0.0


def score_manual(
    T_start: Transform,
    target_xyz: np.ndarray,
    source_xyz: np.ndarray,
    params: CoarseParams,
    cand_id: int,
    label: str,
) -> Candidate:
    """Make a manual pose a candidate: polished and scored as the tetrahedra's are.

    Parameters
    ----------
    T_start : (4, 4) float64
        The technician's ``T_target_source`` (local frames).
    target_xyz, source_xyz : (N, 3), (M, 3) float64
        The preprocessed scans the automatic candidates were verified on.
    params : CoarseParams
    cand_id : int
        Id of the candidate (>= MANUAL_ID_BASE).
    label : str
        How the pose was made ("3 point pairs", "typed transform", ...).

    Returns
    -------
    Candidate
        Origin ``"manual"``; ``T_match`` is the pose as given, ``T_target_source`` the
        polished one.
    """
    return ManualScorer(target_xyz, source_xyz, params).score(T_start, cand_id, label)


class ManualScorer:
    """Scores given poses of one pair of scans as :func:`score_manual` does.

    The verification sample and the target's search structures are made once, so
    several poses of the same pair (the stem poses of a plot link) cost one build.
    """

    def __init__(
        self,
        target_xyz: np.ndarray,
        source_xyz: np.ndarray,
        params: CoarseParams,
        *,
        score_xyz: np.ndarray | None = None,
    ) -> None:
        """Build the verification sample and the search structures.

        ``score_xyz``: the source points the scores are measured on (default: all of
        ``source_xyz``); the polish and its check use all of ``source_xyz``.
        """
        from scipy.spatial import cKDTree

        from amrst.stages.coarse import POLISH_POINTS, verification_sample
        from amrst.stages.polish import Occupancy
        from amrst.stages.voxels import voxel_sample

        self.target_xyz, self.source_xyz, self.params = target_xyz, source_xyz, params
        # Drawn from all points whatever score_xyz is: the polish draws on from the
        # same generator, so its points do not depend on score_xyz.
        self.sample, rng = verification_sample(source_xyz, params)
        if score_xyz is not None:
            self.sample = verification_sample(score_xyz, params)[0]
        self.occupancy = Occupancy(target_xyz, params.verify_voxel_m)
        self.tree = cKDTree(target_xyz)
        if params.polish_top > 0:
            self.tgt_small = target_xyz[voxel_sample(target_xyz, params.verify_voxel_m)]
            src_small = source_xyz[voxel_sample(source_xyz, params.verify_voxel_m)]
            if len(src_small) > POLISH_POINTS:
                src_small = src_small[
                    rng.choice(len(src_small), POLISH_POINTS, replace=False)
                ]
            self.src_small = src_small
            self.small_tree = cKDTree(self.tgt_small)

    def score(self, T_start: Transform, cand_id: int, label: str) -> Candidate:
        """Return the pose ``T_start`` as a candidate (see :func:`score_manual`)."""
        from amrst.review.manual_keep import judge_refinement
        from amrst.stages.candidates import Candidate, Origin
        from amrst.stages.polish import polish

        params, sample = self.params, self.sample
        T_start = np.asarray(T_start, float)
        raw = float(
            self.occupancy.fraction_many(
                (sample @ T_start[:3, :3].T + T_start[:3, 3])[None]
            )[0]
        )
        T_pol = T_start
        note = ""
        if params.polish_top > 0:
            T_pol = polish(
                self.src_small,
                self.tgt_small,
                self.small_tree,
                T_start[None],
                params.polish_max_dist_m,
            )[0]
            kept = judge_refinement(
                T_start,
                T_pol,
                self.target_xyz,
                self.source_xyz,
                params,
                "The short ICP polish",
                tree=self.tree,
            )
            if kept.keep_manual:  # the polish left the technician's solution
                T_pol, note = T_start, " " + kept.why
        d = self.tree.query(
            sample @ T_pol[:3, :3].T + T_pol[:3, 3],
            distance_upper_bound=params.tight_dist_m,
        )[0]
        score = float(np.mean(d < params.tight_dist_m))
        nan = float("nan")
        return Candidate(
            id=int(cand_id),
            rank=0,
            score=score,
            raw_score=raw,
            support=0,
            volume_m3=nan,
            edge_error=nan,
            svd_residual_m=nan,
            target_idx=np.zeros(0, np.int64),
            source_idx=np.zeros(0, np.int64),
            T_match=T_start,
            T_target_source=np.asarray(T_pol),
            polished=params.polish_top > 0 and not note,
            explanation=(
                f"Manual pose ({label}); {score:.0%} of sampled source points lie "
                f"within {params.tight_dist_m * 100:.0f} cm of the target "
                f"{'as given' if note else 'after a short ICP polish'} "
                f"({raw:.0%} on or next to a {params.verify_voxel_m * 100:.0f} cm "
                "target voxel as given)." + note
            ),
            origin=Origin.MANUAL,
        )
