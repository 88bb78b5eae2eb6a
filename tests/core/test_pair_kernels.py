"""The pair stages' fast kernels against reference implementations kept here.

The polish ICP keeps its partners in a NearestCache, the occupancy grid is dilated
axis by axis, and the verification asks the KD-tree only about points the occupancy
test found near the target: each must give what the plain version gave, bit for bit.
"""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial import cKDTree

from amrst.neighbours import NearestTree
from amrst.stages.polish import (
    POLISH_ITERATIONS,
    POLISH_STOP_M,
    POLISH_STOP_RAD,
    Occupancy,
    polish,
    rigid_steps,
)


def _reference_polish(src, tgt, tree, Ts, max_dist, fit=rigid_steps):
    """The polish before the cache: one fresh bounded query per iteration."""
    Ts = np.array(Ts, dtype=float).reshape(-1, 4, 4)
    alive = np.ones(len(Ts), dtype=bool)
    for dist in (max_dist, max_dist / 3):
        moving = alive.copy()
        for _ in range(POLISH_ITERATIONS):
            idx = np.flatnonzero(moving)
            if not len(idx):
                break
            T = Ts[idx]
            moved = np.einsum("bij,nj->bni", T[:, :3, :3], src) + T[:, None, :3, 3]
            d, j = tree.query(moved.reshape(-1, 3), distance_upper_bound=dist)
            ok = (d < dist).reshape(len(idx), -1)
            enough = ok.sum(axis=1) >= 6
            alive[idx[~enough]] = moving[idx[~enough]] = False
            idx, moved, ok = idx[enough], moved[enough], ok[enough]
            if not len(idx):
                break
            partner = tgt[np.minimum(j, len(tgt) - 1)].reshape(-1, len(src), 3)
            step = fit(moved, partner[enough], ok.astype(float))
            Ts[idx] = step @ Ts[idx]
            still = (np.linalg.norm(step[:, :3, 3], axis=1) >= POLISH_STOP_M) | (
                np.trace(step[:, :3, :3], axis1=1, axis2=2) <= 3 - POLISH_STOP_RAD**2
            )
            moving[idx[~still]] = False
    return Ts


def _turn(deg: float, axis: int = 2) -> np.ndarray:
    a = np.radians(deg)
    c, s = np.cos(a), np.sin(a)
    i, j = [k for k in range(3) if k != axis]
    T = np.eye(4)
    T[i, i], T[i, j], T[j, i], T[j, j] = c, -s, s, c
    return T


@pytest.fixture(scope="module")
def crown() -> tuple[np.ndarray, np.ndarray]:
    """A lumpy crown on a trunk as target, a noisy, partial copy as source."""
    rng = np.random.default_rng(7)
    trunk = np.column_stack(
        [
            0.2 * np.cos(t := rng.uniform(0, 2 * np.pi, 800)),
            0.2 * np.sin(t),
            rng.uniform(0, 3, 800),
        ]
    )
    blobs = rng.normal(0, 1.0, (6, 3)) * [1.5, 1.5, 0.8] + [0, 0, 5]
    crown = np.vstack([b + rng.normal(0, 0.5, (500, 3)) for b in blobs])
    tgt = np.vstack([trunk, crown])
    src = tgt[rng.choice(len(tgt), 500, replace=False)] + rng.normal(0, 0.01, (500, 3))
    return src, tgt


@pytest.mark.parametrize("tree_kind", ["ckdtree", "small_gicp"])
def test_polish_with_the_cache_equals_fresh_queries(crown, tree_kind: str) -> None:
    """Near starts, far starts (some die: fewer than 6 partners) and every start moving
    differently: the same transforms bit for bit, on either KD-tree."""
    src, tgt = crown
    starts = [np.eye(4), _turn(4), _turn(-9), _turn(25), _turn(6, axis=0)]
    shifted = _turn(2)
    shifted[:3, 3] = [0.2, -0.1, 0.05]
    far = np.eye(4)
    far[:3, 3] = [50.0, 0, 0]
    Ts = np.stack([*starts, shifted, far])
    tree = cKDTree(tgt) if tree_kind == "ckdtree" else NearestTree(tgt)
    got = polish(src, tgt, tree, Ts, 0.5)
    want = _reference_polish(src, tgt, cKDTree(tgt), Ts, 0.5)
    np.testing.assert_array_equal(got, want)
    np.testing.assert_array_equal(got[-1], far)  # nothing within reach: untouched
    assert np.abs(got[0][:3, 3]).max() < 0.02  # and it does converge


def _reference_occupancy_codes(xyz: np.ndarray, voxel: float) -> np.ndarray:
    """The dilation before: all 27 offsets added at once, one unique."""
    keys = np.floor(xyz / voxel).astype(np.int64)
    keys = keys[np.unique(Occupancy._code(keys), return_index=True)[1]]
    offs = np.array(np.meshgrid([-1, 0, 1], [-1, 0, 1], [-1, 0, 1])).reshape(3, -1).T
    return np.unique(Occupancy._code((keys[:, None, :] + offs[None]).reshape(-1, 3)))


@pytest.mark.parametrize("voxel", [0.05, 0.1, 0.7])
def test_occupancy_dilated_axis_by_axis_equals_all_offsets(voxel: float) -> None:
    rng = np.random.default_rng(3)
    xyz = np.vstack(
        [rng.normal(0, 2, (5000, 3)), rng.uniform(-40, 40, (300, 3)), -xyz_neg()]
    )
    occ = Occupancy(xyz, voxel)
    np.testing.assert_array_equal(occ.codes, _reference_occupancy_codes(xyz, voxel))
    # hits_many against a brute-force neighbourhood test on the voxel keys
    pts = rng.normal(0, 3, (4, 300, 3))
    keys = np.floor(xyz / voxel).astype(np.int64)
    cells = {tuple(k) for k in keys}
    qk = np.floor(pts / voxel).astype(np.int64)
    brute = np.array(
        [
            [
                any(
                    (k[0] + a, k[1] + b, k[2] + c) in cells
                    for a in (-1, 0, 1)
                    for b in (-1, 0, 1)
                    for c in (-1, 0, 1)
                )
                for k in row
            ]
            for row in qk
        ]
    )
    np.testing.assert_array_equal(occ.hits_many(pts), brute)
    np.testing.assert_array_equal(occ.fraction_many(pts), brute.mean(axis=1))


def xyz_neg() -> np.ndarray:
    """Points on negative voxel keys and on voxel borders."""
    return np.array([[0.0, 0.0, 0.0], [0.1, 0.2, 0.3], [3.5, 0.7, 1.4]])


def test_points_within_the_tight_distance_are_all_on_occupied_voxels() -> None:
    """The verification's prefilter: a point closer than the voxel to a target point
    always lands on or next to an occupied voxel, so skipping the others loses none."""
    rng = np.random.default_rng(5)
    tgt = rng.uniform(-3, 3, (4000, 3))
    pts = rng.uniform(-3.5, 3.5, (1, 20000, 3))
    occ = Occupancy(tgt, 0.1)
    d = cKDTree(tgt).query(pts[0], distance_upper_bound=0.1)[0]
    close = d < 0.0999
    assert close.sum() > 500
    assert occ.hits_many(pts)[0][close].all()


def _reference_lm_icp(src, tgt, T_init, max_dist, iters, tol):
    """LM-ICP before the fused sums: fresh queries, np.cross, a BLAS dot product."""
    from amrst.geometry import rotvec_matrix
    from amrst.types import make_transform

    tree = cKDTree(tgt)
    T, lam, prev = T_init.copy(), 1e-3, np.inf
    for it in range(1, iters + 1):
        p = src @ T[:3, :3].T + T[:3, 3]
        d, j = tree.query(p, distance_upper_bound=max_dist)
        ok = d < max_dist
        if ok.sum() < 6:
            return T, it
        p, q = p[ok], tgt[j[ok]]
        e = p - q
        sp = p.sum(axis=0)
        sx = np.array(
            [[0.0, -sp[2], sp[1]], [sp[2], 0.0, -sp[0]], [-sp[1], sp[0], 0.0]]
        )
        H = np.empty((6, 6))
        H[:3, :3] = np.eye(3) * np.einsum("ni,ni->", p, p) - p.T @ p
        H[:3, 3:], H[3:, :3], H[3:, 3:] = sx, -sx, np.eye(3) * len(p)
        g = np.concatenate([np.cross(p, e).sum(axis=0), e.sum(axis=0)])
        e = e.reshape(-1)
        cost = float(e @ e) / len(p)
        for _ in range(10):
            dx = np.linalg.solve(H + lam * np.diag(np.diag(H)), -g)
            dT = make_transform(rotvec_matrix(dx[:3]), dx[3:])
            p2 = p @ dT[:3, :3].T + dT[:3, 3]
            if np.mean(np.sum((p2 - q) ** 2, axis=1)) < cost:
                lam = max(lam / 10, 1e-9)
                T = dT @ T
                break
            lam *= 10
        if abs(prev - cost) <= tol * max(cost, 1e-12):
            return T, it
        prev = cost
    return T, iters


@pytest.mark.parametrize("n", [800, 6000])  # 6000: over OpenBLAS's threaded dot size
def test_lm_icp_equals_the_plain_version(crown, n: int) -> None:
    """Fused sums and a numpy dot product: the same steps, to rounding."""
    from amrst.stages.fine import lm_icp

    _, tgt = crown
    rng = np.random.default_rng(9)
    src = tgt[rng.choice(len(tgt), n)] + rng.normal(0, 0.01, (n, 3))
    start = _turn(3)
    start[:3, 3] = [0.05, -0.04, 0.02]
    T, it, _ = lm_icp(src, tgt, start, 0.3, 30, 1e-7)
    T_ref, it_ref = _reference_lm_icp(src, tgt, start, 0.3, 30, 1e-7)
    assert it == it_ref
    np.testing.assert_allclose(T, T_ref, rtol=0, atol=1e-9)
    assert np.abs(T[:3, 3]).max() < 0.01  # and it converged near the identity


def test_transform_many_equals_the_einsum_it_replaced() -> None:
    from amrst.stages.polish import transform_many

    rng = np.random.default_rng(12)
    Ts = np.tile(np.eye(4), (37, 1, 1))
    Ts[:, :3, :3] = np.linalg.qr(rng.normal(size=(37, 3, 3)))[0]
    Ts[:, :3, 3] = rng.normal(0, 20, (37, 3))
    pts = rng.normal(0, 7, (611, 3))
    want = np.einsum("bij,nj->bni", Ts[:, :3, :3], pts) + Ts[:, None, :3, 3]
    np.testing.assert_array_equal(transform_many(Ts, pts), want)


def test_the_cache_skips_far_points_and_still_equals_fresh_queries() -> None:
    """With the voxel prefilter, points far from the target are never queried, and
    the partners are those of a bounded KD-tree query."""
    from amrst.stages.nearest_cache import NearestCache

    rng = np.random.default_rng(8)
    tgt = rng.uniform(0, 2, (2000, 3))
    occ = Occupancy(tgt, 1.05 * 1.5 * 0.2)
    asked: list[int] = []

    class Counting:
        def __init__(self) -> None:
            self.tree = NearestTree(tgt)

        def query(self, x, k=1, distance_upper_bound=np.inf):
            asked.append(len(x))
            return self.tree.query(x, k, distance_upper_bound)

    p = np.vstack([rng.uniform(-0.1, 2.1, (500, 3)), rng.uniform(5, 9, (500, 3))])
    cache = NearestCache(
        Counting(), tgt, len(p), 0.2, lambda x: occ.hits_many(x[None])[0]
    )
    found, q = cache.match(p)
    assert asked[0] <= 500  # none of the far half
    d, j = cKDTree(tgt).query(p, distance_upper_bound=0.2)
    want = np.flatnonzero(np.isfinite(d))
    np.testing.assert_array_equal(found, want)
    np.testing.assert_array_equal(q, tgt[j[want]])


def test_match_reductions_equal_numpy_reductions() -> None:
    """The tetrahedron screen's column-by-column maxima equal numpy's reductions."""
    from amrst.stages.tetra_screen import _EDGE_PERM, _max_over_edges, _row_max

    rng = np.random.default_rng(2)
    log_s = rng.uniform(0, 3, (5000, 6)).astype(np.float32)
    log_t = rng.uniform(0, 3, (5000, 6)).astype(np.float32)
    want = np.abs(log_s[:, _EDGE_PERM] - log_t[:, None, :]).max(axis=2)
    np.testing.assert_array_equal(_max_over_edges(log_s, log_t), want)
    a = rng.normal(size=(777, 6))
    np.testing.assert_array_equal(_row_max(a), a.max(axis=1))
    edges = rng.uniform(0.1, 20, (3000, 6))
    mean = edges[:, 0].copy()
    for k in range(1, 6):
        mean += edges[:, k]
    np.testing.assert_array_equal(mean / 6, edges.mean(axis=1))


@pytest.mark.parametrize("dense", [True, False])
def test_occupancy_dense_grid_and_sorted_codes_agree(
    dense: bool, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Both representations (dense box, or sorted codes for a huge box) answer alike."""
    monkeypatch.setattr(Occupancy, "MAX_CELLS", 1 << 40 if dense else 0)
    rng = np.random.default_rng(11)
    xyz = np.vstack([rng.normal(0, 1.5, (3000, 3)), xyz_neg()])
    occ = Occupancy(xyz, 0.1)
    assert (occ._grid is not None) == dense
    np.testing.assert_array_equal(occ.codes, _reference_occupancy_codes(xyz, 0.1))
    pts = rng.normal(0, 3, (3, 2000, 3))
    pts[0, :5] = [[1e6, 0, 0], [-1e6, 0, 0], [0, 0, 1e6], [0, 0, -1e6], [0, 1e6, 0]]
    code = Occupancy._code(np.floor(pts / 0.1).astype(np.int64))
    want = np.isin(code, _reference_occupancy_codes(xyz, 0.1))
    np.testing.assert_array_equal(occ.hits_many(pts), want)
    assert not Occupancy(np.zeros((0, 3)), 0.1).hits_many(pts).any()


def test_rotvec_equals_scipy_bit_for_bit() -> None:
    """The one rotation-vector formula: scipy's arithmetic on Python floats, same bits."""
    from scipy.spatial.transform import Rotation

    from amrst.geometry import rotvec_matrix

    rng = np.random.default_rng(2)
    for mag in (0.0, 1e-12, 1e-7, 1e-4, 9e-4, 1e-3, 2e-3, 0.05, 1.0, 3.0, 6.0):
        for _ in range(300):
            w = rng.normal(0, mag, 3)
            np.testing.assert_array_equal(
                rotvec_matrix(w), Rotation.from_rotvec(w).as_matrix()
            )
    near_half_turn = rng.normal(0, 1, (300, 3))
    near_half_turn *= (np.pi - 1e-9) / np.linalg.norm(near_half_turn, axis=1)[:, None]
    for w in near_half_turn:
        np.testing.assert_array_equal(
            rotvec_matrix(w), Rotation.from_rotvec(w).as_matrix()
        )


def test_proper_screen_equals_masking_all_24_orders() -> None:
    """Screening only the proper permutations finds what masking all 24 found."""
    from amrst.stages.tetra_screen import _PARITY, _max_over_edges, _proper_candidates

    rng = np.random.default_rng(4)
    log_t = rng.uniform(0, 1, (3000, 6)).astype(np.float32)
    log_s = (log_t[:, rng.permutation(6)] + rng.normal(0, 0.05, (3000, 6))).astype(
        np.float32
    )
    sign_t = rng.choice([-1.0, 0.0, 1.0], 3000, p=[0.45, 0.1, 0.45])
    sign_s = rng.choice([-1.0, 0.0, 1.0], 3000, p=[0.45, 0.1, 0.45])
    proper = sign_s[:, None] * _PARITY[None, :] == sign_t[:, None]
    rows, cols = np.nonzero((_max_over_edges(log_s, log_t) <= 0.1) & proper)
    want = set(zip(rows.tolist(), cols.tolist(), strict=True))
    pair, perm = _proper_candidates(log_s, log_t, sign_s, sign_t, 0.1)
    got = list(zip(pair.tolist(), perm.tolist(), strict=True))
    assert len(got) == len(set(got)) == len(want) > 100
    assert set(got) == want
