"""The descriptor join of tetrahedron matching: every pair within Chebyshev distance 1.

``amrst.stages.match`` describes each tetrahedron by 7 (or 11, levelled) numbers
scaled so that a Chebyshev distance of 1 is the tolerance on every entry, and needs
all (target, source) pairs within it. A KD-tree in 11 dimensions prunes poorly on
these clustered descriptors (a dual-tree ``cKDTree.sparse_distance_matrix`` is
slow on them). Here the source descriptors are bucketed on a half-unit grid of
two entries (shortest edge and volume) and sorted by the first (longest edge) inside
each bucket: each target reads, for each of the 25 neighbouring buckets, the exact
range of sources within 1 on the longest edge (two ``searchsorted``), and the
candidates are then tested entry by entry, the most selective first. Same pairs as
the tree, exactly: every test is ``|a - b| <= 1`` on the original values.
"""

from __future__ import annotations

import numpy as np

# Entries of the descriptor in the order they are tested: those that reject the most
# candidates on the shared cases first (4th edge, lowest height, 3rd height, 5th
# edge, ...), the longest edge last (its range was already exact to rounding).
_TEST_ORDER = (3, 7, 9, 4, 8, 1, 2, 10, 5, 6, 0)
_SWEEP = 0  # the longest edge: an exact range inside each bucket
_GRID = (5, 6)  # shortest edge and volume: the buckets
_CELL = 0.5  # bucket width (tolerance units): 5 buckets per entry cover the reach


def _tree_pairs(a: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Fallback for descriptors with fewer than 3 entries (the grid needs 3)."""
    from scipy.spatial import cKDTree

    pairs = cKDTree(a, leafsize=32).sparse_distance_matrix(
        cKDTree(b, leafsize=32), 1.0, p=np.inf, output_type="ndarray"
    )
    return pairs["i"].astype(np.int64), pairs["j"].astype(np.int64)


def _grid_candidates(
    A: np.ndarray, B: np.ndarray, grid: tuple[int, ...]
) -> tuple[np.ndarray, np.ndarray]:
    """(target, source) pairs in neighbouring buckets within ~1 on the sweep entry.

    A superset of the pairs within 1 on the sweep and grid entries. ``A``, ``B``: the
    descriptors transposed, (D, n) and (D, m).
    """
    reach = int(np.ceil(1 / _CELL))
    ka = np.zeros(A.shape[1], np.int64)
    kb = np.zeros(B.shape[1], np.int64)
    cells = []
    for d in grid:
        lo = min(A[d].min(), B[d].min())
        ca = np.floor((A[d] - lo) / _CELL).astype(np.int64) + reach
        cb = np.floor((B[d] - lo) / _CELL).astype(np.int64) + reach
        cells.append((ca, cb))
    span = max(max(int(ca.max()), int(cb.max())) for ca, cb in cells) + reach + 1
    for ca, cb in cells:  # mixed-radix bucket number, room for +-reach
        ka = ka * span + ca
        kb = kb * span + cb
    shift = np.zeros(1, np.int64)
    for _ in grid:
        shift = (shift[:, None] * span + np.arange(-reach, reach + 1)).reshape(-1)
    # Sources sorted by (bucket, sweep value) as one float key: bucket * width + value.
    x0 = min(A[_SWEEP].min(), B[_SWEEP].min())
    width = float(np.ceil(max(A[_SWEEP].max(), B[_SWEEP].max()) - x0)) + 4.0
    comp = kb * width + (B[_SWEEP] - x0)
    order = np.argsort(comp, kind="stable")
    comp = comp[order]
    key = ((ka[:, None] + shift[None, :]) * width + (A[_SWEEP] - x0)[:, None]).reshape(
        -1
    )
    # Rounding of the float key: widen the range (the exact test follows).
    slack = 1.0 + 1e-6 + 1e-12 * float(np.abs(comp).max(initial=0.0))
    left = np.searchsorted(comp, key - slack)
    count = np.searchsorted(comp, key + slack, "right") - left
    hit = np.flatnonzero(count)
    count, left = count[hit], left[hit]
    ti = np.repeat(hit // len(shift), count)
    pos = np.arange(len(ti)) + np.repeat(left - np.cumsum(count) + count, count)
    return ti, order[pos]


def descriptor_pairs(
    desc_t: np.ndarray, desc_s: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """All (target, source) descriptor pairs within Chebyshev distance 1, sorted.

    Parameters
    ----------
    desc_t : (n, D) float64
    desc_s : (m, D) float64

    Returns
    -------
    (P,) int64 target and (P,) int64 source indices, sorted by (target, source).
    """
    n, m = len(desc_t), len(desc_s)
    dims = desc_t.shape[1]
    if n == 0 or m == 0:
        return np.zeros(0, np.int64), np.zeros(0, np.int64)
    fin_t, fin_s = np.isfinite(desc_t).all(axis=1), np.isfinite(desc_s).all(axis=1)
    if not (fin_t.all() and fin_s.all()):
        # A non-finite entry (the log of a zero volume) is within 1 of nothing.
        keep_t, keep_s = np.flatnonzero(fin_t), np.flatnonzero(fin_s)
        ti, si = descriptor_pairs(desc_t[keep_t], desc_s[keep_s])
        return keep_t[ti], keep_s[si]
    if dims < 3:
        ti, si = _tree_pairs(desc_t, desc_s)
    else:
        A = np.ascontiguousarray(desc_t.T)
        B = np.ascontiguousarray(desc_s.T)
        grid = _GRID if dims > max(_GRID) else (1, 2)
        ti, si = _grid_candidates(A, B, grid)
        tests = [d for d in _TEST_ORDER if d < dims]
        tests += [d for d in range(dims) if d not in tests]
        # The first two entries on every candidate, then each entry on the survivors.
        first, second = tests[0], tests[1]
        ok = np.abs(A[first][ti] - B[first][si]) <= 1.0
        ok &= np.abs(A[second][ti] - B[second][si]) <= 1.0
        keep = np.flatnonzero(ok)
        ti, si = ti[keep], si[keep]
        for d in tests[2:]:
            keep = np.flatnonzero(np.abs(A[d][ti] - B[d][si]) <= 1.0)
            ti, si = ti[keep], si[keep]
    order = np.argsort(ti * m + si)
    return ti[order], si[order]
