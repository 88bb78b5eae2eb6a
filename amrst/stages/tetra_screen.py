"""The permutation screen of tetrahedron matching: which vertex order of a descriptor pair fits.

Sorted edge lengths lose the vertex order and admit mirror images, so every
descriptor pair found by ``amrst.stages.match`` is checked here under all 24 vertex
permutations (edge agreement, signed volume, levelled heights), and the best proper
one is kept.
"""

from __future__ import annotations

import itertools
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    from amrst.stages.match import MatchParams

EDGES = np.array([(0, 1), (0, 2), (0, 3), (1, 2), (1, 3), (2, 3)])
PERMS = np.array(list(itertools.permutations(range(4))))


def _edge_index(a: int, b: int) -> int:
    return next(i for i, (x, y) in enumerate(EDGES) if {x, y} == {a, b})


# Under vertex permutation π, target edge (a, b) meets source edge (π(a), π(b)); a
# permutation's parity flips the signed volume. Both are fixed tables.
_EDGE_PERM = np.array([[_edge_index(p[a], p[b]) for a, b in EDGES] for p in PERMS])
_PARITY = np.array([np.linalg.det(np.eye(4)[list(p)]) for p in PERMS])
_EVEN = np.flatnonzero(_PARITY > 0)
_ODD = np.flatnonzero(_PARITY < 0)
_ALL = np.arange(len(PERMS))


def _row_max(a: np.ndarray) -> np.ndarray:
    """``a.max(axis=1)`` of a (P, k) array, column by column (exact, and faster)."""
    out: np.ndarray = a[:, 0].copy()
    for k in range(1, a.shape[1]):
        np.maximum(out, a[:, k], out=out)
    return out


def _max_over_edges(
    log_s: np.ndarray, log_t: np.ndarray, perms: np.ndarray | None = None
) -> np.ndarray:
    """(P, K) max over the six edges of ``|log_s[:, _EDGE_PERM[perms]] - log_t[:, None]|``.

    ``perms``: the K permutations asked (None: all 24).
    """
    table = _EDGE_PERM if perms is None else _EDGE_PERM[perms]
    out: np.ndarray = np.abs(log_s[:, table[:, 0]] - log_t[:, :1])
    for k in range(1, 6):
        np.maximum(out, np.abs(log_s[:, table[:, k]] - log_t[:, k : k + 1]), out=out)
    return out


def _proper_candidates(
    log_s: np.ndarray,
    log_t: np.ndarray,
    sign_s: np.ndarray,
    sign_t: np.ndarray,
    limit: float,
) -> tuple[np.ndarray, np.ndarray]:
    """(pair, permutation) of the proper orders whose log edges agree within ``limit``.

    A permutation is proper when its parity times the source volume's sign is the
    target volume's sign: for pairs of equal signs the 12 even permutations, for
    opposite signs the 12 odd ones (zero volumes: all or none). Only those are
    screened (half the work of screening all 24 and masking).
    """
    pairs, perms = [], []
    for group, allowed in (
        (np.flatnonzero((sign_s == sign_t) & (sign_t != 0)), _EVEN),
        (np.flatnonzero((sign_s == -sign_t) & (sign_t != 0)), _ODD),
        (np.flatnonzero((sign_s == 0) & (sign_t == 0)), _ALL),
    ):
        if not len(group):
            continue
        dlog = _max_over_edges(log_s[group], log_t[group], allowed)
        pair, perm = np.nonzero(dlog <= limit)
        pairs.append(group[pair])
        perms.append(allowed[perm])
    if not pairs:
        return np.zeros(0, np.int64), np.zeros(0, np.int64)
    return np.concatenate(pairs), np.concatenate(perms)


def correspond(
    target_kp: np.ndarray,
    source_kp: np.ndarray,
    ti: np.ndarray,
    si: np.ndarray,
    params: MatchParams,
    *,
    tq: np.ndarray,
    sq: np.ndarray,
    te: np.ndarray,
    se: np.ndarray,
    tv: np.ndarray,
    sv: np.ndarray,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """For descriptor pairs, the proper vertex permutation whose edges agree best.

    Sorted edges lose the vertex order and admit mirror images (same edges, opposite
    signed volume); all 24 orders are tried and improper ones are excluded.
    Returns the pairs kept, the permutation index and the edge error.
    """
    c = params.edge_floor_m
    # The relative edge error |a - b| / (max(a, b) + c) is 1 - exp(-|log(a+c) -
    # log(b+c)|): screen all 24 orders on float32 log lengths (no division), with a
    # little slack, then compute the exact error and the other tests on the few survivors.
    log_t = np.log(te[ti] + c).astype(np.float32)
    log_s = np.log(se[si] + c).astype(np.float32)
    # max over the six edges of |log_s[perm] - log_t|, one edge at a time (numpy
    # reduces a short last axis slowly), on the proper permutations only.
    limit = -np.log1p(-params.edge_tolerance) + 1e-5  # slack >> float32 rounding
    pair, perm = _proper_candidates(
        log_s, log_t, np.sign(sv[si]), np.sign(tv[ti]), limit
    )
    e_s = se[si[pair]][np.arange(len(pair))[:, None], _EDGE_PERM[perm]]
    e_t = te[ti[pair]]
    err = _row_max(np.abs(e_s - e_t) / (np.maximum(e_s, e_t) + c))
    ok = err <= params.edge_tolerance
    if params.levelled:
        zt = target_kp[tq[ti[pair]], 2]
        zs = source_kp[sq[si[pair]], 2][np.arange(len(pair))[:, None], PERMS[perm]]
        dz = (zt - zt.mean(axis=1, keepdims=True)) - (
            zs - zs.mean(axis=1, keepdims=True)
        )
        ok &= np.abs(dz).max(axis=1) <= params.height_tolerance_m
    pair, perm, err = pair[ok], perm[ok], err[ok]
    # Per pair the smallest error; on a tie the first permutation (as argmin would).
    order = np.lexsort((perm, err, pair))
    first = (
        order[np.r_[True, pair[order][1:] != pair[order][:-1]]] if len(order) else order
    )
    return ti[pair[first]], si[pair[first]], perm[first], err[first]
