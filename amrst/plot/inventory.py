"""The inventory of a registered plot: every tree listed once, measured on all scans.

The scans are merged on the reference's frame and the stem map is made once on the
merged plot, so a tree seen from several positions is one stem there (with more of
its circumference, hence a better DBH). Each tree records the scans with points on
it 0.3-2.5 m above its foot (``seen_from``). Trees are numbered by position (west to east, then
south to north, on a 10 cm grid), so the same files give the same ids.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import TYPE_CHECKING, Any

import numpy as np

from amrst.plot.stemmap import StemMap, StemMapParams, map_stems
from amrst.sampling import strided

if TYPE_CHECKING:
    from collections.abc import Collection, Mapping, Sequence

    from amrst.plot.stemmap import StemRecord
    from amrst.progress import Reporter
    from amrst.types import Cloud, Transform

#: Columns of a tree's figures in trees.csv, in order (``mark`` follows them).
TREE_COLUMNS = (
    "tree_id",
    "x_m",
    "y_m",
    "z_m",
    "height_m",
    "height_flag",
    "height_seen_m",
    "dbh_m",
    "dbh_quality",
    "dbh_arc_deg",
    "dbh_rmse_m",
    "dbh_outlier_share",
    "dbh_why",
    "lean_deg",
    "crown_width_m",
    "n_points",
    "seen_from",
)
#: A scan sees a tree when this many of its points (1 cm thinned) lie on the tree
#: 0.3-2.5 m above its foot.
SEEN_POINTS = 30
#: A crown this close to the farthest range of every scan may be cut off (m).
RANGE_MARGIN_M = 0.5
#: A scan's range is read from about this many of its points.
REACH_POINTS = 200_000
#: A tree's top is seen when a scan saw this far above it (m) ...
PROBE_M = 0.5
#: ... through a line of sight with fewer than SIGHT_POINTS points within
#: SIGHT_RADIUS_M of it (sampled every SIGHT_STEP_M, up to SIGHT_END_M short).
SIGHT_POINTS = 5
SIGHT_RADIUS_M = 0.1
SIGHT_STEP_M = 0.05
SIGHT_END_M = 0.3
#: The height flag of a tree whose top no scan could be checked against: no scan of
#: the plot says where its scanner stood (a georeferenced LAS, say).
NOT_CHECKED = "top not checked"
#: The height flag of a tree whose top lies at the edge of every scan's range: the
#: crown went on beyond what any scan kept, so its height is not known.
OUT_OF_RANGE = "top out of range"
#: A scan's file origin farther than this from its points is not where its scanner
#: stood (m): the scan was moved into other coordinates.
ORIGIN_GAP_M = 50.0


@dataclass(frozen=True, slots=True)
class Tree:
    """One tree of the plot: its stem record and where it stands in the output frame."""

    tree_id: str
    stem: StemRecord
    xyz: np.ndarray  # (3,) stem base in the reference frame, world when offset
    seen_from: tuple[int, ...]  # 1-based scan numbers

    def row(self) -> dict[str, Any]:
        """Return the tree's trees.csv row (numbers rounded to what they mean)."""
        s = self.stem
        return {
            "tree_id": self.tree_id,
            "x_m": round(float(self.xyz[0]), 3),
            "y_m": round(float(self.xyz[1]), 3),
            "z_m": round(float(self.xyz[2]), 3),
            "height_m": _rounded(s.height_m, 2),
            "height_flag": s.height_flag,
            "height_seen_m": _rounded(s.height_seen_m, 2),
            "dbh_m": _rounded(s.dbh_m, 4),
            "dbh_quality": s.dbh_quality,
            "dbh_arc_deg": _rounded(s.arc_deg, 0),
            "dbh_rmse_m": _rounded(s.rmse_m, 4),
            "dbh_outlier_share": _rounded(s.outlier_share, 2),
            "dbh_why": s.dbh_why,
            "lean_deg": _rounded(s.lean_deg, 1),
            "crown_width_m": _rounded(s.crown_width_m, 2),
            "n_points": s.n_points,
            "seen_from": ";".join(str(k) for k in self.seen_from),
        }

    @classmethod
    def from_row(
        cls, row: dict[str, str], offset: np.ndarray, dbh_xy: np.ndarray
    ) -> Tree:
        """Return the tree a trees.csv row lists (figures as rounded there).

        Its base goes into the local frame of ``offset``; ``dbh_xy`` is its
        breast-height centre there (not in trees.csv).

        Raises
        ------
        KeyError, ValueError
            A column missing, or a figure that is no number.
        """
        from amrst.plot.stemmap import StemRecord

        xyz = np.array([float(row[c]) for c in ("x_m", "y_m", "z_m")])
        stem = StemRecord(
            base=xyz - np.asarray(offset, float),
            dbh_xy=np.asarray(dbh_xy, float),
            dbh_m=_number(row["dbh_m"]),
            arc_deg=_number(row["dbh_arc_deg"]),
            rmse_m=_number(row["dbh_rmse_m"]),
            outlier_share=_number(row["dbh_outlier_share"]),
            dbh_quality=row["dbh_quality"],
            dbh_why=row.get("dbh_why", ""),
            height_m=_number(row["height_m"]),
            height_flag=row["height_flag"],
            height_seen_m=_number(row.get("height_seen_m", "")),
            lean_deg=_number(row["lean_deg"]),
            crown_width_m=_number(row["crown_width_m"]),
            n_points=int(row["n_points"]),
        )
        seen = tuple(int(k) for k in row["seen_from"].split(";") if k.strip())
        return cls(row["tree_id"], stem, xyz, seen)


def _rounded(value: float, digits: int) -> float | str:
    return "" if not np.isfinite(value) else round(float(value), digits)


def _number(text: str) -> float:
    """Return a trees.csv figure: an empty cell is NaN (not measured)."""
    return float(text) if text.strip() else float("nan")


@dataclass(frozen=True, slots=True)
class Inventory:
    """Every tree of the plot, and the merged stem map it was read from."""

    trees: tuple[Tree, ...]
    stem_map: StemMap
    scan_of_point: np.ndarray  # (N,) scan index of each stem-map working point

    @property
    def why_none(self) -> str:
        """Why the plot lists no tree ("" when it lists one), for the technician."""
        if self.trees:
            return ""
        if not self.stem_map.ground.found:
            return (
                "no ground was found under the registered plot, and trees are "
                "measured from it: check that the scans are z-up and show the ground "
                "around the stems"
            )
        return (
            "no stem stands on the ground found under the registered plot: check "
            "that the scans are z-up and show the stems down to the ground"
        )

    def tree_points(self, k: int) -> np.ndarray:
        """(M, 3) the points of tree k (reference local frame)."""
        return np.asarray(self.stem_map.xyz[self.stem_map.owner == k])


def seen_from_any(trees: Sequence[Tree], scans: Collection[int]) -> int:
    """Return how many of ``trees`` are seen from one of ``scans`` (from 1)."""
    return sum(1 for t in trees if not set(scans).isdisjoint(t.seen_from))


def merge_scans(
    clouds: Sequence[Cloud],
    poses: Sequence[Transform | None],
    reporter: Reporter | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Every reached scan's points on the reference frame, and their scan."""
    parts, owners = [], []
    for k, (cloud, pose) in enumerate(zip(clouds, poses, strict=True)):
        if pose is None:
            continue
        if reporter is not None:
            reporter.check_cancelled()
            reporter.progress(0.2 * k / len(clouds), f"merging scan {k + 1}")
        parts.append(cloud.xyz @ pose[:3, :3].T + pose[:3, 3])
        owners.append(np.full(len(cloud), k, dtype=np.int64))
    return np.vstack(parts), np.concatenate(owners)


def take_inventory(
    clouds: Sequence[Cloud],
    poses: Sequence[Transform | None],
    reference: int = 0,
    reporter: Reporter | None = None,
    given: Mapping[str, tuple[float, float]] | None = None,
) -> Inventory:
    """List every tree of the registered plot once.

    Trees found are numbered ``T001``... by their position; the trees the technician
    gave (``given``, where the inventory lists no tree) keep the ids given, so that
    neither numbering moves the other.

    Parameters
    ----------
    clouds : sequence of Cloud
        The plot's scans as it keeps them (``PlotScan.analysis.cloud``: the stem
        map's working points of each).
    poses : sequence of (4, 4) float64 or None
        Scan k's local frame -> the reference's local frame (None: not placed).
    reference : int
        The frame of the output; its offset makes the positions world coordinates.
    reporter : Reporter or None
    given : mapping of tree id to (x, y), or None
        Where the technician says a tree stands, in the reference's local frame.

    Returns
    -------
    Inventory
    """
    from amrst.progress import SubReporter

    xyz, scan = merge_scans(clouds, poses, reporter)
    # The merged points are thinned once more: overlapping scans double the density.
    stem_map = map_stems(
        xyz,
        StemMapParams(),
        None if reporter is None else SubReporter(reporter, 0.2, 0.95),
        given=given,
    )
    assert stem_map.index is not None  # map_stems gives the rows it kept
    scan = scan[stem_map.index]
    if reporter is not None:
        reporter.progress(0.95, "tops out of every scan's sight")
    stem_map = _flag_hidden_tops(stem_map, _scanner_reach(clouds, poses))
    offset = np.asarray(clouds[reference].offset, dtype=float)
    stems = stem_map.stems
    found = [k for k, s in enumerate(stems) if s.given is None]
    given_stems = sorted(
        (k for k, s in enumerate(stems) if s.given is not None),
        key=lambda k: stems[k].given or "",
    )
    order = sorted(found, key=lambda k: tuple(np.round(stems[k].base[:2], 1)))
    ids = [f"T{n:03d}" for n in range(1, len(order) + 1)]
    ids += [stems[k].given or "" for k in given_stems]
    order += given_stems
    trees = [
        Tree(tree_id, stems[k], stems[k].base + offset, _seen_from(stem_map, scan, k))
        for tree_id, k in zip(ids, order, strict=True)
    ]
    renumber = np.full(len(order) + 1, -1, dtype=np.int64)
    renumber[np.array(order, dtype=np.int64)] = np.arange(len(order))
    owner = renumber[stem_map.owner]
    stems = tuple(stem_map.stems[k] for k in order)
    merged = StemMap(stems, stem_map.ground, stem_map.xyz, owner)
    return Inventory(tuple(trees), merged, scan)


def _seen_from(stem_map: StemMap, scan: np.ndarray, k: int) -> tuple[int, ...]:
    """1-based scans with at least ``SEEN_POINTS`` points on stem k's lower part.

    The points are the tree's own (``owner``), so a leaning stem, or one whose
    breast-height centre is off its foot, counts the points its scans put on it.
    """
    h = stem_map.xyz[:, 2] - stem_map.stems[k].base[2]
    on = (stem_map.owner == k) & (h >= 0.3) & (h <= 2.5)
    counts = np.bincount(scan[on], minlength=int(scan.max()) + 1 if len(scan) else 0)
    return tuple(int(s) + 1 for s in np.flatnonzero(counts >= SEEN_POINTS))


def scanner_at(cloud: Cloud) -> np.ndarray | None:
    """(3,) where the scanner stood, in the cloud's local frame; None when unknown.

    A multi-scan file (E57, PTX) says where (``meta["scanner_origin"]``, in the
    file's coordinates), whether its scans were read posed or not. Any other scan is
    taken to be in its scanner's frame, its scanner at the file's origin, as an
    unregistered export is (a scan cropped to the plot need not surround it); a
    georeferenced one (an offset over ``LARGE_COORD_M``) that does not say is unknown,
    and so is a position, said or taken, over ``ORIGIN_GAP_M`` from its points' box.
    """
    from amrst.io.common import LARGE_COORD_M

    if not len(cloud.xyz):
        return None
    said = cloud.meta.get("scanner_origin")
    if said is not None and len(said) == 3:
        origin = np.asarray(np.asarray(said, dtype=float) - cloud.offset, dtype=float)
    elif np.abs(cloud.offset).max() > LARGE_COORD_M:
        return None
    else:
        origin = np.asarray(-cloud.offset, dtype=float)
    lo, hi = cloud.xyz.min(axis=0), cloud.xyz.max(axis=0)
    gap = float(np.linalg.norm(np.maximum(lo - origin, 0) + np.maximum(origin - hi, 0)))
    return None if gap > ORIGIN_GAP_M else origin  # far off its points: no scanner


def scanner_in_reference(cloud: Cloud, pose: Transform | None) -> np.ndarray | None:
    """(3,) the scanner of a scan placed by ``pose``, in the reference's local frame."""
    at = scanner_at(cloud)
    if pose is None or at is None:
        return None
    return np.asarray(pose[:3, :3] @ at + pose[:3, 3], dtype=float)


def _scanner_reach(
    clouds: Sequence[Cloud], poses: Sequence[Transform | None]
) -> list[tuple[np.ndarray, float]]:
    """Each placed scan's scanner (reference frame) and range, where it is known.

    The range is the 99.9th percentile of its points' distances from the scanner,
    over about ``REACH_POINTS`` of them (:func:`amrst.sampling.strided`): a 10M-point
    scan costs no more.
    """
    out = []
    for cloud, pose in zip(clouds, poses, strict=True):
        at, where = scanner_at(cloud), scanner_in_reference(cloud, pose)
        if at is None or where is None or not len(cloud.xyz):
            continue
        every = strided(cloud.xyz, REACH_POINTS) - at
        reach = float(np.percentile(np.linalg.norm(every, axis=1), 99.9))
        out.append((where, reach))
    return out


def _flag_hidden_tops(
    stem_map: StemMap, reach: Sequence[tuple[np.ndarray, float]]
) -> StemMap:
    """Flag the trees whose top no scan could have seen above.

    A tree's highest point is its top only if a scan saw the space just above it
    (``PROBE_M`` higher) empty: within that scan's range, and with no point near the
    line of sight in front of it. Where the highest point itself lies at the edge of
    every scan's range, the crown went on beyond what any scan kept: the height is
    not known (``top out of range``, ``height_seen_m`` how high it was seen).
    Otherwise a crown that reaches the edge of every scan's range elsewhere, or a
    top seen by no scan, is ``top not seen``.
    """
    if not reach:  # no scan says where its scanner stood: no top can be checked
        return replace(
            stem_map,
            stems=tuple(
                replace(s, height_flag=NOT_CHECKED) if s.height_flag == "ok" else s
                for s in stem_map.stems
            ),
        )
    from scipy.spatial import cKDTree

    kd = cKDTree(stem_map.xyz)
    stems = []
    for k, s in enumerate(stem_map.stems):
        mine = stem_map.xyz[stem_map.owner == k]
        if not len(mine) or not np.isfinite(s.height_m):
            stems.append(s)
            continue
        top = mine[np.argmin(np.abs(mine[:, 2] - (s.base[2] + s.height_m)))]
        if all(
            np.linalg.norm(top - origin) > r - RANGE_MARGIN_M for origin, r in reach
        ):
            out = replace(s, height_m=float("nan"), height_seen_m=s.height_m)
            stems.append(replace(out, height_flag=OUT_OF_RANGE))
            continue
        probe = top + np.array([0.0, 0.0, PROBE_M])
        seen = any(
            np.linalg.norm(probe - origin) <= r and _clear(kd, origin, probe)
            for origin, r in reach
        )
        to_edge = np.array(
            [r - np.linalg.norm(mine - origin, axis=1) for origin, r in reach]
        )
        cut = bool(np.any(np.all(to_edge < RANGE_MARGIN_M, axis=0)))
        hidden = cut or not seen
        stems.append(replace(s, height_flag="top not seen") if hidden else s)
    return replace(stem_map, stems=tuple(stems))


def _clear(kd: Any, origin: np.ndarray, target: np.ndarray) -> bool:
    """Tell whether the line of sight from ``origin`` to ``target`` passes no points.

    Samples every ``SIGHT_STEP_M`` from half a metre out to ``SIGHT_END_M`` short of
    the target; at most ``SIGHT_POINTS`` points within ``SIGHT_RADIUS_M`` of them.
    """
    ray = target - origin
    length = float(np.linalg.norm(ray))
    t = np.arange(0.5, max(length - SIGHT_END_M, 0.5), SIGHT_STEP_M)
    samples = origin + np.outer(t / length, ray)
    near = kd.query_ball_point(samples, SIGHT_RADIUS_M, return_length=True)
    return int(np.sum(near)) < SIGHT_POINTS
