"""What ``amrst info`` and the app's Scans dock say about a cloud.

Size, world bounds, median spacing on a seeded sample, attributes and format
metadata (:func:`describe`), and its text form (:func:`format_description`); the
scans a file of several holds, from their headers (:func:`format_scan_list`).
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

import numpy as np

if TYPE_CHECKING:
    from collections.abc import Sequence

    from amrst.io.posed import ScanInfo
    from amrst.types import Cloud

_SPACING_SAMPLE = 20_000
_SLAB_ROWS = 250_000  # rows sorted at once when looking for copies


def describe(cloud: Cloud) -> dict[str, Any]:
    """Summary numbers for ``amrst info``: size, bounds, spacing, attributes, format.

    Parameters
    ----------
    cloud : Cloud

    Returns
    -------
    dict
        ``name``, ``n_points``, ``offset``, ``bounds_min``/``bounds_max`` (world, m),
        ``extent`` (m), ``median_spacing_m`` (median nearest-neighbour distance of
        at most 20000 seeded random points, or None), ``attributes`` (name ->
        ``{"dtype", "shape", "min", "max"}``) and ``format`` (JSON-friendly meta).
    """
    n = len(cloud)
    # Column by column: numpy reduces a C-ordered (N, 3) array across rows much
    # slower than each strided column, and the app describes every scan it opens.
    xyz = cloud.xyz
    lo = (
        np.array([xyz[:, k].min() for k in range(3)]) + cloud.offset
        if n
        else np.full(3, np.nan)
    )
    hi = (
        np.array([xyz[:, k].max() for k in range(3)]) + cloud.offset
        if n
        else np.full(3, np.nan)
    )
    return {
        "name": cloud.name,
        "n_points": n,
        "offset": cloud.offset.tolist(),
        "bounds_min": lo.tolist(),
        "bounds_max": hi.tolist(),
        "extent": (hi - lo).tolist(),
        "median_spacing_m": median_spacing(cloud.xyz),
        "attributes": {k: _describe_array(v) for k, v in cloud.attributes.items()},
        "format": _plain_meta(cloud.meta),
    }


def median_spacing(xyz: np.ndarray) -> float | None:
    """Median nearest-neighbour distance of a seeded sample, in linear-ish time.

    Identical points are merged before the k-d trees are built: a tree holding
    many copies of one point answers each query in time proportional to the
    copies. A sample point with a copy has distance 0.

    The work goes slab by slab along x (:func:`_slabs`), one small tree each: numpy's
    sorts and scipy's tree set-up hold the GIL, so one sort or one tree of every
    point of a big scan would stall the window while this runs in a worker.
    A sample point asks its own slab's tree, then any other slab nearer than the
    neighbour found so far, so the distances are those of one tree of all points.
    """
    from scipy.spatial import cKDTree

    n = len(xyz)
    if n < 2:
        return None
    rng = np.random.default_rng(0)
    sample = rng.choice(n, size=min(n, _SPACING_SAMPLE), replace=False)
    slabs = _slabs(xyz)
    copied_rows = np.empty(n, dtype=bool)
    slab_of = np.empty(n, dtype=np.int32)
    trees, lo, hi = [], [], []
    for k, rows in enumerate(slabs):
        distinct, copied_rows[rows] = _merge_sorted(xyz[rows])
        slab_of[rows] = k
        trees.append(cKDTree(distinct, balanced_tree=False, compact_nodes=False))
        lo.append(distinct[:, 0].min())
        hi.append(distinct[:, 0].max())
    copied = copied_rows[sample]
    dist = np.zeros(len(sample))
    ask = sample[~copied]
    if len(ask):
        q, own = xyz[ask], slab_of[ask]
        best = np.full(len(ask), np.inf)
        for k, tree in enumerate(trees):  # own slab first: the second neighbour
            mine = np.flatnonzero(own == k)
            if len(mine) and tree.n >= 2:
                best[mine] = tree.query(q[mine], k=2)[0][:, 1]
        for k, tree in enumerate(trees):  # then any slab nearer than that
            gap = np.maximum(lo[k] - q[:, 0], q[:, 0] - hi[k])
            near = np.flatnonzero((own != k) & (gap < best))
            if len(near):
                best[near] = np.minimum(best[near], tree.query(q[near], k=1)[0])
        dist[~copied] = best
    return float(np.median(dist))


def _slabs(xyz: np.ndarray) -> list[np.ndarray]:
    """Split the rows into slabs along x, at most about ``_SLAB_ROWS`` each.

    Identical rows share their x, so they share a slab. The edges are a sample's
    quantiles; the rows are assigned by one comparison pass per edge (no sort of
    all rows, which would hold the GIL for its whole length).
    """
    n = len(xyz)
    if n <= _SLAB_ROWS:
        return [np.arange(n)]
    x = np.ascontiguousarray(xyz[:, 0])
    n_slabs = -(-n // _SLAB_ROWS)
    probe = x[np.random.default_rng(0).integers(0, n, 20 * n_slabs)]
    edges = np.unique(np.quantile(probe, np.linspace(0, 1, n_slabs + 1)[1:-1]))
    slab = np.zeros(n, dtype=np.int16)
    for edge in edges:
        slab += x > edge
    found = (np.flatnonzero(slab == k) for k in range(len(edges) + 1))
    return [rows for rows in found if len(rows)]


def _merge_sorted(xyz: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Distinct rows of ``xyz``, and (N,) bool: the row has an identical copy.

    One lexsort of the three columns: ``np.unique(axis=0)`` compares whole rows,
    which is much slower.
    """
    order = np.lexsort((xyz[:, 2], xyz[:, 1], xyz[:, 0]))
    ranked = xyz[order]
    same = np.all(ranked[1:] == ranked[:-1], axis=1)  # row i+1 equals row i
    if not same.any():
        return xyz, np.zeros(len(xyz), dtype=bool)
    in_run = np.zeros(len(xyz), dtype=bool)
    in_run[1:] |= same
    in_run[:-1] |= same
    copied = np.empty(len(xyz), dtype=bool)
    copied[order] = in_run
    first = np.ones(len(xyz), dtype=bool)
    first[1:] = ~same
    return ranked[first], copied


def _describe_array(arr: np.ndarray) -> dict[str, Any]:
    finite = arr[np.isfinite(arr)] if arr.dtype.kind == "f" else arr
    has = finite.size > 0
    return {
        "dtype": str(arr.dtype),
        "shape": list(arr.shape[1:]),
        "min": finite.min().item() if has else None,
        "max": finite.max().item() if has else None,
    }


def _plain_meta(meta: Any) -> dict[str, Any]:
    out: dict[str, Any] = {}
    for key, value in meta.items():
        if key == "las_vlrs":
            out["las_vlrs"] = [f"{v[0]}/{v[1]} {v[2]}".strip() for v in value]
        elif isinstance(value, (str, int, float, bool)) or value is None:
            out[key] = value
        elif isinstance(value, (tuple, list)) and all(
            isinstance(v, (str, int, float, bool)) for v in value
        ):
            out[key] = list(value)
    return out


def format_description(d: dict[str, Any]) -> str:
    """Human-readable multi-line text of a :func:`describe` dict.

    Parameters
    ----------
    d : dict
        The output of :func:`describe`.

    Returns
    -------
    str
        Lines such as ``points      12,345``; no trailing newline.
    """

    def xyz(values: Sequence[float], digits: int = 3) -> str:
        return "  ".join(f"{v:.{digits}f}" for v in values)

    spacing = d["median_spacing_m"]
    lines = [
        d["name"] or "(unnamed cloud)",
        f"  points      {d['n_points']:,}",
        f"  offset      {xyz(d['offset'])}",
        f"  min         {xyz(d['bounds_min'])}",
        f"  max         {xyz(d['bounds_max'])}",
        f"  extent      {xyz(d['extent'])} m",
        "  spacing     "
        + ("n/a" if spacing is None else f"{spacing:.4f} m (median nearest neighbour)"),
        f"  attributes  {len(d['attributes']) or 'none'}",
    ]
    width = max((len(k) for k in d["attributes"]), default=0)
    for name, info in d["attributes"].items():
        shape = f"x{info['shape']}" if info["shape"] else ""
        lines.append(
            f"    {name:<{width}}  {info['dtype']}{shape}  "
            f"min {_num(info['min'])}  max {_num(info['max'])}"
        )
    fmt = d["format"]
    details = [f"{k}={v}" for k, v in fmt.items() if k not in ("path", "format")]
    lines.append(
        f"  format      {fmt.get('format', '?')}  {', '.join(details)}".rstrip()
    )
    return "\n".join(lines)


def format_scan_list(name: str, infos: Sequence[ScanInfo]) -> str:
    """Text of the scans a file of several holds: one line a scan, from its header.

    Parameters
    ----------
    name : str
        The file's name.
    infos : sequence of ScanInfo
        Its scans (:func:`amrst.io.scans.list_scans`).

    Returns
    -------
    str
        A title line, then ``#k``, name, points, where the scanner stood when the
        file says (or that its pose is not usable), and the fields; no trailing
        newline.
    """
    from amrst.io.posed import pose_problem

    total = sum(i.n_points for i in infos)
    rows = [
        (
            f"#{i.index}",
            i.name or "-",
            f"{i.n_points:,}",
            "pose not usable"
            if pose_problem(np.asarray(i.T_world_scanner)) is not None
            else "0.000  0.000  0.000 (no pose: its own frame)"
            if i.scanner_xyz is None
            else "  ".join(f"{v:.3f}" for v in i.scanner_xyz),
            ", ".join(i.fields) or "none",
        )
        for i in infos
    ]
    head = ("scan", "name", "points", "scanner at (x y z)", "fields")
    widths = [max(len(r[c]) for r in [head, *rows]) for c in range(len(head))]
    lines = [f"{name}: {len(infos)} scans, {total:,} points"]
    for row in [head, *rows]:
        cells = [f"{v:<{w}}" for v, w in zip(row, widths, strict=True)]
        cells[2] = f"{row[2]:>{widths[2]}}"
        lines.append("  " + "  ".join(cells).rstrip())
    lines.append(f"  amrst info {name}#K describes scan K.")
    return "\n".join(lines)


def _num(value: Any) -> str:
    if value is None:
        return "n/a"
    return f"{value:.6g}" if isinstance(value, float) else str(value)
