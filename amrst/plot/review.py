"""The technician's review of a plot, kept in ``review.json`` beside the inventory.

It names the scans it belongs to, by path and by content (``scan_ids``: a folder of
scans moved or copied elsewhere keeps its review; with scans added or removed around
the same reference it holds for the trees, whose positions are in that scan's frame;
a review of another reference is not applied), and holds

- ``marks``: ``ok`` / ``check`` / ``not a tree`` per tree id, with ``at``, where each
  marked tree's stem stood (breast height, the reference scan's local frame). A run
  that lists the trees otherwise moves each mark, and each DBH by hand, to the tree
  now standing there (:func:`followed`);
- ``dbh``: the technician's own DBH of a tree, a circle placed on its breast-height
  slice (:func:`hand_circle`); it stands beside the measured one, and holds across a
  run again as marks do;
- ``added``: where the technician says a tree stands that the inventory did not
  list (the reference scan's local frame), by the id it is listed under (``H001``...,
  never reused while the point stays); each run measures a tree there
  (``amrst.plot.inventory``);
- ``accepted``: links the registration left unsure that the technician checked by eye
  and accepted, each with the pose accepted (the source scan's file coordinates into
  the target's, as ``plot.json`` gives poses). An acceptance holds only while the
  link keeps that pose (within ``SAME_POSE_DEG``, and ``SAME_POSE_M`` where the
  source scan's points are): a run that places the link elsewhere asks for a new
  look.

A scan's ``status`` in ``plot.json`` stays what the registration found; its ``state``
(:func:`scan_state`) is what a person sees with the review: ``accepted`` when every
unsure link of its path was accepted at the pose it has.
"""

from __future__ import annotations

import os
import re
from dataclasses import dataclass, field, replace
from typing import TYPE_CHECKING, Any

import numpy as np

from amrst.campaign.folder import ACCEPTED as ACCEPTED  # a scan the review accepted
from amrst.errors import InvalidInput
from amrst.geometry import kasa_circle
from amrst.review.verdict import NEEDS_REVIEW
from amrst.types import check_rigid, invert_transform

#: How much of each end of a scan file its identity hashes (:func:`scan_id`).
ID_BYTES = 1 << 16

if TYPE_CHECKING:
    from collections.abc import Iterable, Mapping, Sequence
    from pathlib import Path

    from amrst.types import Transform

REVIEW_JSON = "review.json"
#: The technician's marks of a tree; an unmarked tree has none. ``not a tree``: a
#: shrub, a pole or a part of a neighbour listed as a tree (it stays listed, marked).
NOT_A_TREE = "not a tree"
MARKS = ("ok", "check", NOT_A_TREE)
#: An accepted pose holds for a link within this turn (deg) and shift (m): under what
#: the overlay shows, over the few-thread rounding of one run to the next.
SAME_POSE_DEG = 0.05
SAME_POSE_M = 0.01

#: The id of a tree the technician added: H and a number (H001), apart from the
#: found trees' T001... and safe as a file name (trees/H001.ply).
ADDED_ID = r"H[0-9]{1,6}"
#: Positions in review.json are in the reference scan's frame, whose origin is among
#: its points: a tree added farther than this (m) stands in no plot.
MAX_LOCAL_M = 1e5
#: A DBH by hand is under this (m): a wider circle is clicks along a line.
MAX_HAND_DBH_M = 4.0
#: A mark belongs to the tree standing within this (m) of where it was given; a DBH by
#: hand, within this or its own diameter of its circle's centre.
FOLLOW_M = 0.3
#: An added tree is listed as a tree found when one stands this near its point (m):
#: the found stem's foot within 0.3 m of it, its breast height leaning a little more.
FOUND_NEAR_M = 0.6

LinkKey = tuple[int, int]  # (target scan, source scan), from 0


@dataclass(frozen=True, slots=True)
class HandCircle:
    """A stem circle the technician placed at breast height: their DBH of the tree."""

    centre_xy: tuple[float, float]  # the reference scan's local frame (view.npz's)
    dbh_m: float


@dataclass(frozen=True, slots=True)
class PlotReview:
    """The technician's marks and DBHs per tree id, and links accepted (with pose)."""

    marks: dict[str, str] = field(default_factory=dict)
    accepted: dict[LinkKey, np.ndarray] = field(default_factory=dict)
    dbh: dict[str, HandCircle] = field(default_factory=dict)
    added: dict[str, tuple[float, float]] = field(default_factory=dict)
    at: dict[str, tuple[float, float]] = field(default_factory=dict)


def hand_circle(xy: np.ndarray) -> HandCircle | None:
    """Return the circle that fits points clicked on a stem's outline (least squares).

    None for fewer than three points, or points too near a line to bound a stem
    (a circle wider than ``MAX_HAND_DBH_M``).
    """
    pts = np.asarray(xy, float).reshape(-1, 2)
    if len(pts) < 3 or not np.isfinite(pts).all():
        return None
    centre, r2 = kasa_circle(pts, pts.mean(axis=0))
    if not 0 < r2 < (MAX_HAND_DBH_M / 2) ** 2:
        return None
    return HandCircle((float(centre[0]), float(centre[1])), float(2 * np.sqrt(r2)))


def followed(
    review: PlotReview, trees_xy: Mapping[str, np.ndarray]
) -> tuple[PlotReview, bool, list[str]]:
    """Return the review moved onto the trees standing where it was given.

    Also whether it moved, and what of it found no tree (e.g. ``T003 (check)``).
    Marks and DBHs by hand go to the tree standing where they were given.
    ``trees_xy``: each listed tree's breast-height centre by id. A mark with no
    position (an older review) stays on its id; one that no tree stands near any more
    (within ``FOLLOW_M``) is dropped, as is a DBH whose circle no stem lies under
    and a tree added where the run lists none (out of every scan's sight), under
    its id or near it.
    """
    ids = list(trees_xy)
    xy = np.array([trees_xy[k][:2] for k in ids], float).reshape(-1, 2)

    def nearest(p: tuple[float, float], reach: float) -> str | None:
        if not ids:
            return None
        d = np.hypot(*(xy - p).T)
        d[~np.isfinite(d)] = np.inf
        k = int(np.argmin(d))
        return ids[k] if d[k] <= reach else None

    marks: dict[str, str] = {}
    at: dict[str, tuple[float, float]] = {}
    lost: list[str] = []
    for tree_id, mark in review.marks.items():
        if tree_id not in review.at:
            marks.setdefault(tree_id, mark)
            continue
        now = nearest(review.at[tree_id], FOLLOW_M)
        if now is not None and now not in at:
            x, y = xy[ids.index(now)]
            marks[now], at[now] = mark, (float(x), float(y))
        else:
            lost.append(f"{tree_id} ({mark})")
    dbh: dict[str, HandCircle] = {}
    for tree_id, c in review.dbh.items():
        now = nearest(c.centre_xy, max(FOLLOW_M, c.dbh_m))
        if now is not None and now not in dbh:
            dbh[now] = c
        else:
            lost.append(f"{tree_id} (your DBH {100 * c.dbh_m:.1f} cm)")
    listed = listed_added(review, trees_xy)
    added = {k: p for k, p in review.added.items() if k in listed}
    lost += [f"{k} (added)" for k in review.added if k not in listed]
    moved = (
        marks != review.marks
        or at != review.at
        or dbh != review.dbh
        or added != review.added
    )
    return replace(review, marks=marks, at=at, dbh=dbh, added=added), moved, lost


def listed_added(review: PlotReview, trees_xy: Mapping[str, np.ndarray]) -> set[str]:
    """Return the ids of the added trees a run lists.

    Under their own id, or as a tree found at their point (within ``FOUND_NEAR_M``);
    ``trees_xy`` as :func:`followed` takes it.
    """
    xy = np.array([p[:2] for p in trees_xy.values()], float).reshape(-1, 2)
    listed = set()
    for tree_id, p in review.added.items():
        d = np.hypot(*(xy - p).T)
        if tree_id in trees_xy or bool((d <= FOUND_NEAR_M).any()):
            listed.add(tree_id)
    return listed


def next_added_id(review: PlotReview) -> str:
    """Return the id the next tree the technician adds is listed under."""
    numbers = [int(k[1:]) for k in review.added if k[1:].isdigit()]
    return f"H{max(numbers, default=0) + 1:03d}"


def without_added(review: PlotReview, tree_id: str) -> PlotReview:
    """Return the review without the added tree ``tree_id``, its mark and its DBH."""
    return replace(
        review,
        marks={k: v for k, v in review.marks.items() if k != tree_id},
        dbh={k: v for k, v in review.dbh.items() if k != tree_id},
        added={k: v for k, v in review.added.items() if k != tree_id},
        at={k: v for k, v in review.at.items() if k != tree_id},
    )


def review_document(out: Path) -> Any:
    """Read the JSON ``out``'s review.json holds, safely (a named pipe is refused).

    Raises InvalidInput when it cannot be read as JSON.
    """
    from amrst.files.safefile import load_json_file

    return load_json_file(
        out / REVIEW_JSON,
        "review file",
        "the review.json the app wrote, or move it away",
    )


def read_review(out: Path, labels: Sequence[str]) -> PlotReview:
    """Return the review ``out`` holds for this plot (empty: none, or other scans').

    A review of scans added or removed around the same reference holds for its trees
    and for the accepted links whose two scans are still there.

    Raises InvalidInput when the file cannot be read as a review.
    """
    path = out / REVIEW_JSON
    if not os.path.lexists(path):
        return PlotReview()
    if not path.is_file():
        raise InvalidInput(f"{path} is not a file: move it away to review the plot.")
    doc = review_document(out)
    field = "scans"  # the field read, for the message when it cannot be
    try:
        if not isinstance(doc, dict):
            raise TypeError("not a JSON object")
        scans = [str(label) for label in list(doc["scans"])]
        field = "marks"
        marks = {str(k): str(v) for k, v in dict(doc["marks"]).items()}
        field = "accepted"
        accepted = {
            _key(k): check_rigid(T, f"the pose accepted for link {k}")
            for k, T in dict(doc.get("accepted") or {}).items()
        }
        field = "dbh"
        dbh = {str(k): _circle(v) for k, v in dict(doc.get("dbh") or {}).items()}
        field = "added"
        points = [_point(n, v) for n, v in enumerate(list(doc.get("added") or []))]
        added = dict(points)
        if len(added) < len(points):
            raise _Unfit("two trees added under one id")
        field = "at"
        at = {str(k): _xy(v) for k, v in dict(doc.get("at") or {}).items()}
    except (
        InvalidInput,  # an accepted pose that is no rigid transform
        OSError,
        ValueError,
        KeyError,
        TypeError,
        OverflowError,
        RecursionError,
    ) as exc:
        what = (
            "it is no JSON object"
            if not isinstance(doc, dict)
            else f"it has no {field!r}"
            if field not in doc
            else f"its {field!r} is not what the app writes"
            + (f" ({exc})" if isinstance(exc, (InvalidInput, _Unfit)) else "")
        )
        raise InvalidInput(
            f"{path} is no review file: {what}; move it away to review the plot again."
        ) from exc
    if any(v not in MARKS for v in marks.values()):
        raise InvalidInput(
            f"{path}: a mark is not one of {', '.join(MARKS)}; fix or move the file."
        )
    ids = doc.get("scan_ids")
    if same_scans(scans, labels, ids):
        return PlotReview(marks, accepted, dbh, added, at)
    if not same_reference(scans, labels, ids):
        return PlotReview()
    # Scans added or removed around the same reference: positions are in its frame,
    # so the trees' review holds; an accepted link, where both its scans still are.
    now = [scan_id(label) for label in labels]
    where = [
        _index_in(label, _id_of(ids, k), labels, now) for k, label in enumerate(scans)
    ]
    moved: dict[LinkKey, np.ndarray] = {}
    for (i, j), T in accepted.items():
        a, b = (where[k] if k < len(where) else None for k in (i, j))
        if a is not None and b is not None:  # a link is (lower, higher) scan
            moved[min(a, b), max(a, b)] = T if a < b else invert_transform(T)
    return PlotReview(marks, moved, dbh, added, at)


def same_reference(a: Sequence[str], b: Sequence[str], a_ids: Any = None) -> bool:
    """Tell whether two lists of scan labels start with the same scan (the reference).

    ``a_ids`` as for :func:`same_scans`.
    """
    return bool(a) and bool(b) and same_scans(a[:1], b[:1], _id_of(a_ids, 0))


def _id_of(ids: Any, k: int) -> list[Any] | None:
    """Return the recorded id of scan ``k`` as a list of one (None: not recorded)."""
    return [ids[k]] if isinstance(ids, list) and k < len(ids) else None


def _index_in(
    label: str, label_id: list[Any] | None, labels: Sequence[str], ids: Sequence[str]
) -> int | None:
    """Return where the scan ``label`` (recorded id as :func:`_id_of`) is in ``labels``.

    ``ids`` are the :func:`scan_id` of ``labels``, read once for all.
    """
    key, recorded = _scan_key(label), (label_id or [None])[0]
    for k, other in enumerate(labels):
        if _scan_key(other) == key or (
            isinstance(recorded, str) and recorded and recorded == ids[k]
        ):
            return k
    return None


def same_scans(a: Sequence[str], b: Sequence[str], a_ids: Any = None) -> bool:
    """Tell whether two lists of scan labels name the same scans in the same order.

    A label is a file (``FILE`` or ``FILE#k``, one scan of several); files are
    compared as resolved paths, so the app's absolute paths and the ones typed on
    the command line match. Where the paths differ, ``a_ids`` (the
    :func:`scan_id` of each of ``a``, as recorded) are compared with ``b``'s files
    as they are now: the same scans moved or copied elsewhere.
    """
    if len(a) != len(b):
        return False
    if all(_scan_key(x) == _scan_key(y) for x, y in zip(a, b, strict=True)):
        return True
    if not isinstance(a_ids, list) or len(a_ids) != len(b):
        return False
    return all(
        isinstance(i, str) and i and i == scan_id(y)
        for i, y in zip(a_ids, b, strict=True)
    )


def _scan_ids(out: Path, labels: Sequence[str]) -> list[str]:
    """Each scan's :func:`scan_id`, as ``out``'s review recorded it where it did.

    Kept, not read again: a review saved while the scans are elsewhere (results
    opened on another computer) must not lose the ids that find them again, and a
    mark need not read every scan file.
    """
    try:
        doc = review_document(out)
        known = dict(zip(doc["scans"], doc["scan_ids"], strict=True))
    except (InvalidInput, ValueError, KeyError, TypeError):
        known = {}
    return [
        known[label]
        if isinstance(known.get(label), str) and known[label]
        else scan_id(label)
        for label in labels
    ]


def scan_id(label: str) -> str:
    """Return a scan's identity by content ("" when its file cannot be read).

    Its file's size and a hash of the file's first and last ``ID_BYTES``, and ``#k``
    for one scan of several.
    """
    import hashlib
    from pathlib import Path

    path, part = _file_and_scan(label)
    try:
        with Path(path).open("rb") as fh:
            size = os.fstat(fh.fileno()).st_size
            digest = hashlib.sha1(fh.read(ID_BYTES), usedforsecurity=False)
            fh.seek(max(0, size - ID_BYTES))
            digest.update(fh.read(ID_BYTES))
    except OSError:
        return ""
    return f"{size}:{digest.hexdigest()}{part}"


def _scan_key(label: str) -> str:
    from pathlib import Path

    path, part = _file_and_scan(label)
    return f"{Path(path).resolve()}{part}"


def _file_and_scan(label: str) -> tuple[str, str]:
    """Split ``FILE#k`` into the file and ``#k`` ("" for a file of one scan)."""
    head, sep, tail = str(label).rpartition("#")
    return (head, f"#{tail}") if sep and tail.isdigit() else (str(label), "")


def write_review(out: Path, labels: Sequence[str], review: PlotReview) -> None:
    """Write the review into ``out`` (atomically)."""
    from amrst.files.atomic import write_json_atomic

    bad = sorted(v for v in review.marks.values() if v not in MARKS)
    if bad:
        raise InvalidInput(f"marks are {' or '.join(MARKS)}, not {bad[0]!r}")
    for tree_id, c in review.dbh.items():
        if not _usable(c):
            raise InvalidInput(f"{tree_id}: a DBH by hand of {c.dbh_m} m")
    for n, (tree_id, (x, y)) in enumerate(review.added.items()):
        try:  # what read_review would refuse is not written
            _point(n, {"id": tree_id, "x_m": x, "y_m": y})
        except ValueError as exc:
            raise InvalidInput(f"Not saved: {exc}.") from exc
    accepted = {
        f"{i + 1}-{j + 1}": np.asarray(T, float).tolist()
        for (i, j), T in sorted(review.accepted.items())
    }
    dbh = {
        tree_id: {"x_m": c.centre_xy[0], "y_m": c.centre_xy[1], "dbh_m": c.dbh_m}
        for tree_id, c in sorted(review.dbh.items())
    }
    write_json_atomic(
        out / REVIEW_JSON,
        {
            "scans": list(labels),
            "scan_ids": _scan_ids(out, labels),
            "marks": dict(sorted(review.marks.items())),
            "accepted": accepted,
            "dbh": dbh,
            "added": [
                {"id": k, "x_m": x, "y_m": y} for k, (x, y) in review.added.items()
            ],
            "at": {k: [x, y] for k, (x, y) in sorted(review.at.items())},
        },
    )


def pose_change(
    accepted: Transform, T: Transform, at: np.ndarray
) -> tuple[float, float]:
    """How far ``T`` is from the accepted pose: (turn in deg, shift in m of ``at``).

    ``at`` is a point among the source scan's (file coordinates, e.g. its offset):
    at the origin of a georeferenced frame the tiniest turn would read metres.
    """
    from amrst.types import rotation_angle_deg

    a, b = np.asarray(accepted, float), np.asarray(T, float)
    p = np.asarray(at, float)
    turn = rotation_angle_deg(a[:3, :3].T @ b[:3, :3])
    moved = (a[:3, :3] - b[:3, :3]) @ p + a[:3, 3] - b[:3, 3]
    return turn, float(np.linalg.norm(moved))


def holding(
    accepted: Mapping[LinkKey, Transform],
    links: Iterable[tuple[LinkKey, str, Transform | None, np.ndarray]],
) -> set[LinkKey]:
    """Return the links that need review and keep the pose accepted for them.

    ``links``: (key, status, pose, a point among the source scan's) of each link.
    """
    return {
        key
        for key, status, T, at in links
        if status == NEEDS_REVIEW
        and key in accepted
        and still_holds(accepted[key], T, at)
    }


def still_holds(accepted: Transform, T: Transform | None, at: np.ndarray) -> bool:
    """Tell whether an acceptance of ``accepted`` still holds for a link at ``T``."""
    if T is None:
        return False
    turn, shift = pose_change(accepted, T, at)
    return turn <= SAME_POSE_DEG and shift <= SAME_POSE_M


def scan_state(
    status: str, doubts: frozenset[LinkKey] | None, accepted: set[LinkKey]
) -> str:
    """Return a scan's state with the review (``accepted``, or its ``status``).

    ``accepted`` when it needs review only for links the technician accepted.

    ``doubts``: the unsure links its pose rests on (None: none a person can clear,
    e.g. two registered links disagree about it).
    """
    if status == NEEDS_REVIEW and doubts and doubts <= accepted:
        return ACCEPTED
    return status


def unsure_scans(states: Sequence[str]) -> frozenset[int]:
    """Return the scans, numbered from 1, whose state is *needs review*.

    A tree seen from one rests on a pose nobody confirmed yet (``scans_to_check``).
    """
    return frozenset(k + 1 for k, s in enumerate(states) if s == NEEDS_REVIEW)


class _Unfit(ValueError):
    """A value of review.json that is read but cannot be right (its message says)."""


def _circle(entry: Mapping[str, float]) -> HandCircle:
    circle = HandCircle(
        (float(entry["x_m"]), float(entry["y_m"])), float(entry["dbh_m"])
    )
    if not _usable(circle):
        raise _Unfit(f"a DBH by hand of {circle.dbh_m} m")
    return circle


def _xy(value: Any) -> tuple[float, float]:
    x, y = (float(v) for v in value)
    if not np.isfinite([x, y]).all():
        raise _Unfit("a tree marked at no finite position")
    return x, y


def _point(n: int, entry: Mapping[str, Any]) -> tuple[str, tuple[float, float]]:
    x, y = float(entry["x_m"]), float(entry["y_m"])
    if not (abs(x) <= MAX_LOCAL_M and abs(y) <= MAX_LOCAL_M):  # NaN too
        raise _Unfit(f"a tree added at ({x}, {y}), out of any plot")
    tree_id = str(entry.get("id") or f"H{n + 1:03d}")
    if not re.fullmatch(ADDED_ID, tree_id):
        raise _Unfit(f"an added tree's id {tree_id!r} is not H and a number")
    return tree_id, (x, y)


def _usable(circle: HandCircle) -> bool:
    return (
        bool(np.isfinite(circle.centre_xy).all()) and 0 < circle.dbh_m < MAX_HAND_DBH_M
    )


def _key(text: str) -> LinkKey:
    i, j = (int(v) for v in str(text).split("-"))
    if i < 1 or j < 1:
        raise _Unfit(f"link {text!r}: scans are numbered from 1")
    return i - 1, j - 1
