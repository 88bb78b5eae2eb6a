"""What ``amrst info`` and the app's Scans dock say about a cloud.

Size, world bounds, median spacing on a seeded sample, attributes and format
metadata (:func:`describe`), and its text form (:func:`format_description`).
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

import numpy as np

if TYPE_CHECKING:
    from collections.abc import Sequence

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
    # Column by column: min(axis=0) of an (N, 3) array is 15x slower (10M points:
    # 0.7 s against 0.05 s), and the app describes every scan it opens.
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
        "median_spacing_m": _median_spacing(cloud.xyz),
        "attributes": {k: _describe_array(v) for k, v in cloud.attributes.items()},
        "format": _plain_meta(cloud.meta),
    }


def _median_spacing(xyz: np.ndarray) -> float | None:
    """Median nearest-neighbour distance of a seeded sample, in linear-ish time.

    Identical points are merged before the k-d tree is built: a tree holding
    many copies of one point answers each query in time proportional to the
    copies (1M points at the origin made ``amrst info`` take minutes). A sample
    point with a copy has distance 0, as before.
    """
    from scipy.spatial import cKDTree

    if len(xyz) < 2:
        return None
    rng = np.random.default_rng(0)
    sample = rng.choice(len(xyz), size=min(len(xyz), _SPACING_SAMPLE), replace=False)
    unique, copied_rows = _merge_copies(xyz)
    copied = copied_rows[sample]
    dist = np.zeros(len(sample))
    if len(unique) >= 2 and not copied.all():
        # Query the sample against all points: a tree of the sample alone would
        # overestimate the spacing of a large cloud.
        tree = cKDTree(unique, balanced_tree=False, compact_nodes=False)
        found, _ = tree.query(xyz[sample[~copied]], k=2)
        dist[~copied] = found[:, 1]
    return float(np.median(dist))


def _merge_copies(xyz: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Distinct rows of ``xyz``, and (N,) bool: the row has an identical copy.

    Identical rows share their x, so the rows are split into slabs along x (edges
    from a sample's quantiles) and each slab is sorted on its own: numpy's sorts
    hold the GIL, and one lexsort of 10M rows (0.3-0.4 s) stalled the window while
    a scan's description ran in a worker; a slab takes a few ms. The distinct
    rows come slab by slab (their order is not the input's).
    """
    n = len(xyz)
    if n <= _SLAB_ROWS:
        return _merge_sorted(xyz)
    x = np.ascontiguousarray(xyz[:, 0])
    n_slabs = -(-n // _SLAB_ROWS)
    probe = x[np.random.default_rng(0).integers(0, n, 20 * n_slabs)]
    edges = np.unique(np.quantile(probe, np.linspace(0, 1, n_slabs + 1)[1:-1]))
    slab = np.zeros(n, dtype=np.int16)
    for edge in edges:  # one comparison pass per edge (no sort of all rows)
        slab += x > edge
    uniques, copied = [], np.empty(n, dtype=bool)
    for k in range(len(edges) + 1):
        rows = np.flatnonzero(slab == k)
        if len(rows):
            distinct, has_copy = _merge_sorted(xyz[rows])
            uniques.append(distinct)
            copied[rows] = has_copy
    if not copied.any():
        return xyz, copied
    return np.concatenate(uniques), copied


def _merge_sorted(xyz: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Return what :func:`_merge_copies` does, by one lexsort of all rows.

    About 0.3 s per million points; ``np.unique(axis=0)`` takes ten times longer.
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


def _num(value: Any) -> str:
    if value is None:
        return "n/a"
    return f"{value:.6g}" if isinstance(value, float) else str(value)
