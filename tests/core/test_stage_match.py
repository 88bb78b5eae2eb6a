"""Tetrahedron matching on key point sets related by a known transform, and kabsch()."""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
import pytest

from amrst.stages.match import MatchParams, kabsch, match_tetrahedra


def _rot(axis: str, angle_deg: float) -> np.ndarray:
    from scipy.spatial.transform import Rotation

    return Rotation.from_euler(axis, angle_deg, degrees=True).as_matrix()


def _angle_deg(Ra: np.ndarray, Rb: np.ndarray) -> np.ndarray:
    """Angle(s) between rotations, (..., 3, 3) against (3, 3)."""
    c = (np.einsum("...ij,ij->...", Ra, Rb) - 1.0) / 2.0
    return np.degrees(np.arccos(np.clip(c, -1.0, 1.0)))


class KeyPointPair(NamedTuple):
    source: np.ndarray  # (25, 3) P
    target: np.ndarray  # (26, 3) Q: 21 moved points of P + 5 outliers, shuffled
    partner: np.ndarray  # (26,) source index of each target point, -1 for outliers
    R: np.ndarray
    t: np.ndarray


def _pair(R: np.ndarray, seed: int = 42) -> KeyPointPair:
    """P: 25 random points in a 10 m box; Q = R P + t + 2 cm noise, with 4 points of
    P missing and 5 outliers added, in shuffled order."""
    rng = np.random.default_rng(seed)
    t = np.array([3.0, -2.0, 0.5])
    P = rng.uniform(-5.0, 5.0, (25, 3))
    kept = np.arange(4, 25)
    Q = P[kept] @ R.T + t + rng.normal(0.0, 0.02, (len(kept), 3))
    outliers = rng.uniform(-5.0, 5.0, (5, 3)) @ R.T + t
    order = rng.permutation(len(kept) + 5)
    target = np.vstack([Q, outliers])[order]
    partner = np.r_[kept, np.full(5, -1)][order]
    return KeyPointPair(P, target, partner, R, t)


@pytest.fixture(scope="module")
def levelled_pair() -> KeyPointPair:
    return _pair(_rot("z", 70.0))


@pytest.fixture(scope="module")
def levelled_matches(levelled_pair):
    p = levelled_pair
    return match_tetrahedra(p.target, p.source, MatchParams())


def _true_partners(m, partner: np.ndarray) -> np.ndarray:
    """(P,) True where every vertex pair of a match is a true partner pair."""
    return np.all(partner[m.target_idx] == m.source_idx, axis=1)


def test_matching_recovers_the_known_transform(levelled_pair, levelled_matches) -> None:
    p, m = levelled_pair, levelled_matches
    n = len(m.T_target_source)
    assert n > 100
    assert m.target_idx.shape == m.source_idx.shape == (n, 4)
    assert m.T_target_source.shape == (n, 4, 4)
    assert m.n_descriptor_pairs >= n
    assert np.all(m.svd_residual_m <= MatchParams().max_residual_m)
    best = int(np.argmin(m.svd_residual_m))
    T = m.T_target_source[best]
    assert _angle_deg(T[:3, :3], p.R) < 0.5
    assert np.linalg.norm(T[:3, 3] - p.t) < 0.05
    # The stored transform is the Kabsch fit of the stored vertex pairs.
    src, tgt = p.source[m.source_idx[best]], p.target[m.target_idx[best]]
    moved = src @ T[:3, :3].T + T[:3, 3]
    rms = np.sqrt(np.mean(np.sum((moved - tgt) ** 2, axis=1)))
    assert rms == pytest.approx(m.svd_residual_m[best], abs=1e-9)
    assert rms < 0.05  # 2 cm noise per point


def test_vertex_correspondence_is_right(levelled_pair, levelled_matches) -> None:
    p, m = levelled_pair, levelled_matches
    good = _true_partners(m, p.partner)
    best = int(np.argmin(m.svd_residual_m))
    assert good[best], "the best match pairs the wrong vertices"
    near_truth = _angle_deg(m.T_target_source[:, :3, :3], p.R) < 1.0
    # Every match that reproduces the truth pairs the true partners, vertex by vertex.
    assert near_truth.sum() > 100
    np.testing.assert_array_equal(good, near_truth)


def test_mirror_images_are_rejected(levelled_pair) -> None:
    """Mirroring x -> -x keeps every edge length: only the signed volume tells a
    tetrahedron from its mirror image. A large residual δ makes the volume check the
    only guard (a proper rotation fits a flat mirrored tetrahedron within metres)."""
    p = levelled_pair
    params = MatchParams(levelled=False, max_residual_m=2.0)
    mirrored = p.target * [-1.0, 1.0, 1.0]
    m = match_tetrahedra(mirrored, p.source, params)
    assert not _true_partners(m, p.partner).any(), "a mirrored tetrahedron matched"
    control = match_tetrahedra(p.target, p.source, params)
    assert _true_partners(control, p.partner).sum() > 100


def test_levelled_rule_rejects_a_tilted_solution() -> None:
    """The same pair, but the truth also tilts the vertical by 30 deg."""
    R = _rot("x", 30.0) @ _rot("z", 70.0)
    p = _pair(R, seed=3)
    levelled = match_tetrahedra(p.target, p.source, MatchParams(levelled=True))
    free = match_tetrahedra(p.target, p.source, MatchParams(levelled=False))
    assert not np.any(_angle_deg(levelled.T_target_source[:, :3, :3], R) < 2.0)
    if len(levelled.T_target_source):
        tilt = np.degrees(np.arccos(np.clip(levelled.T_target_source[:, 2, 2], -1, 1)))
        assert tilt.max() <= MatchParams().max_tilt_deg + 1e-9
    near = _angle_deg(free.T_target_source[:, :3, :3], R) < 1.0
    assert near.sum() > 100
    assert _true_partners(free, p.partner)[near].all()
    best = int(np.argmin(free.svd_residual_m))
    assert _angle_deg(free.T_target_source[best, :3, :3], R) < 0.5
    assert np.linalg.norm(free.T_target_source[best, :3, 3] - p.t) < 0.05


def test_too_few_key_points_give_no_match() -> None:
    pts = np.random.default_rng(0).uniform(-5, 5, (3, 3))
    m = match_tetrahedra(pts, pts, MatchParams())
    assert len(m.T_target_source) == 0
    assert m.n_target_tetra == m.n_source_tetra == 0


def test_kabsch_agrees_with_scipy_align_vectors() -> None:
    from scipy.spatial.transform import Rotation

    rng = np.random.default_rng(11)
    B, K = 20, 6
    src = rng.normal(size=(B, K, 3)) * 3.0
    R_true = Rotation.random(B, random_state=12).as_matrix()
    t_true = rng.normal(size=(B, 3)) * 10.0
    dst = np.einsum("bij,bkj->bki", R_true, src) + t_true[:, None]
    dst = dst + rng.normal(0, 0.05, dst.shape)
    T, res = kabsch(src, dst)
    assert T.shape == (B, 4, 4)
    assert res.shape == (B,)
    for b in range(B):
        cs, cd = src[b].mean(axis=0), dst[b].mean(axis=0)
        ref, _ = Rotation.align_vectors(dst[b] - cd, src[b] - cs)
        R_ref = ref.as_matrix()
        np.testing.assert_allclose(T[b, :3, :3], R_ref, atol=1e-9)
        np.testing.assert_allclose(T[b, :3, 3], cd - R_ref @ cs, atol=1e-9)
        moved = src[b] @ R_ref.T + cd - R_ref @ cs
        rms = np.sqrt(np.mean(np.sum((moved - dst[b]) ** 2, axis=1)))
        assert res[b] == pytest.approx(rms, rel=1e-9)
        np.testing.assert_allclose(T[b, 3], [0, 0, 0, 1])
    assert np.allclose(np.linalg.det(T[:, :3, :3]), 1.0)


def test_kabsch_never_returns_a_reflection() -> None:
    """dst is the mirror image of src: the best *proper* rotation is returned."""
    from scipy.spatial.transform import Rotation

    rng = np.random.default_rng(2)
    src = rng.normal(size=(1, 8, 3))
    dst = src * [-1.0, 1.0, 1.0]
    T, res = kabsch(src, dst)
    assert np.linalg.det(T[0, :3, :3]) == pytest.approx(1.0)
    cs, cd = src[0].mean(axis=0), dst[0].mean(axis=0)
    ref, _ = Rotation.align_vectors(dst[0] - cd, src[0] - cs)
    np.testing.assert_allclose(T[0, :3, :3], ref.as_matrix(), atol=1e-9)
    assert res[0] > 0.1


@pytest.mark.parametrize("n", [4, 5, 9, 32])
def test_combinations4_matches_itertools(n) -> None:
    import itertools

    from amrst.geometry import combinations4

    expected = np.array(list(itertools.combinations(range(n), 4)))
    np.testing.assert_array_equal(combinations4(n), expected)


def test_descriptor_pairs_agree_with_brute_force() -> None:
    from amrst.stages.match import _descriptor_pairs

    rng = np.random.default_rng(7)
    desc_t = rng.uniform(0.0, 6.0, (300, 5))
    desc_s = rng.uniform(0.0, 6.0, (250, 5))
    desc_s[:20] = desc_t[:20] + 1.0  # pairs exactly on the boundary count
    ti, si = _descriptor_pairs(desc_t, desc_s)
    close = np.all(np.abs(desc_t[:, None, :] - desc_s[None, :, :]) <= 1.0, axis=2)
    want_t, want_s = np.nonzero(close)  # row-major: sorted by (target, source)
    assert len(want_t) > 50
    np.testing.assert_array_equal(ti, want_t)
    np.testing.assert_array_equal(si, want_s)


@pytest.mark.parametrize("dims", [3, 7, 11])
def test_descriptor_join_equals_the_kd_tree_and_brute_force(dims: int) -> None:
    """The bucket join gives the dual-tree KD search's pairs, on clustered descriptors too."""
    from scipy.spatial import cKDTree

    from amrst.stages.descriptor_join import descriptor_pairs

    rng = np.random.default_rng(dims)
    centres = rng.uniform(0.0, 30.0, (6, dims))  # clusters, like the largest tetrahedra
    desc_t = centres[rng.integers(0, 6, 900)] + rng.normal(0, 0.7, (900, dims))
    desc_s = centres[rng.integers(0, 6, 800)] + rng.normal(0, 0.7, (800, dims))
    desc_s[:30] = desc_t[:30] + rng.choice([-1.0, 0.0, 1.0], (30, dims))  # on the bound
    ti, si = descriptor_pairs(desc_t, desc_s)
    close = np.all(np.abs(desc_t[:, None, :] - desc_s[None, :, :]) <= 1.0, axis=2)
    want_t, want_s = np.nonzero(close)
    assert len(want_t) > 100
    np.testing.assert_array_equal(ti, want_t)
    np.testing.assert_array_equal(si, want_s)
    tree = cKDTree(desc_t).sparse_distance_matrix(
        cKDTree(desc_s), 1.0, p=np.inf, output_type="ndarray"
    )
    assert len(tree) == len(ti)


def test_descriptor_join_handles_empty_and_non_finite_descriptors() -> None:
    from amrst.stages.descriptor_join import descriptor_pairs

    ti, si = descriptor_pairs(np.zeros((0, 7)), np.ones((5, 7)))
    assert len(ti) == len(si) == 0
    desc_t = np.ones((4, 7))
    desc_t[1, 6] = -np.inf  # log of a zero volume
    ti, si = descriptor_pairs(desc_t, np.ones((3, 7)))
    np.testing.assert_array_equal(ti, np.repeat([0, 2, 3], 3))
    np.testing.assert_array_equal(si, np.tile([0, 1, 2], 3))


def _reference_tetrahedra(xyz, params):
    """``_tetrahedra`` before the flat-index edges and per-coordinate volumes (verbatim)."""
    from amrst.geometry import combinations4
    from amrst.stages.tetra_screen import EDGES

    quads = combinations4(len(xyz))
    v = xyz[quads]
    dist = np.linalg.norm(xyz[:, None, :] - xyz[None, :, :], axis=2)
    edges = np.column_stack([dist[quads[:, a], quads[:, b]] for a, b in EDGES])
    signed = (
        np.einsum(
            "ti,ti->t",
            v[:, 1] - v[:, 0],
            np.cross(v[:, 2] - v[:, 0], v[:, 3] - v[:, 0]),
        )
        / 6
    )
    mean_edge = edges[:, 0].copy()
    for k in range(1, 6):
        mean_edge += edges[:, k]
    mean_edge /= 6
    flatness = np.abs(signed) / (mean_edge**3 / (6 * np.sqrt(2)))
    ok = (edges.min(axis=1) >= params.min_edge_m) & (flatness >= params.min_flatness)
    quads, edges, signed = quads[ok], edges[ok], signed[ok]
    order = np.argsort(-np.abs(signed), kind="stable")[: params.max_tetrahedra]
    return quads[order], edges[order], signed[order]


@pytest.mark.parametrize(("n", "cap"), [(6, 3000), (24, 3000), (32, 500)])
def test_tetrahedra_equal_the_plain_version_bit_for_bit(n: int, cap: int) -> None:
    from amrst.stages.match import MatchParams, _tetrahedra

    rng = np.random.default_rng(n)
    xyz = rng.normal(0, 3.0, (n, 3)) + np.array([500.0, -200.0, 30.0])
    xyz[1] = xyz[0] + 0.2  # a short edge: rejected
    params = MatchParams(max_tetrahedra=cap)
    got = _tetrahedra(xyz, params)
    want = _reference_tetrahedra(xyz, params)
    assert len(want[0]) > 0
    for a, b in zip(got, want, strict=True):
        np.testing.assert_array_equal(a, b)
