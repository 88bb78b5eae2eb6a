"""The neighbour table's index-only read (rows with missing neighbours found without a
sort) against a brute-force answer and a reference implementation kept here."""

from __future__ import annotations

import numpy as np
import pytest

from amrst.neighbours import NeighbourTable


def _brute_knn(xyz: np.ndarray, k: int, rows: np.ndarray) -> np.ndarray:
    """Indices of the k nearest points of ``xyz[rows]`` by a full distance matrix."""
    d2 = ((xyz[rows][:, None, :] - xyz[None, :, :]) ** 2).sum(axis=2)
    return np.argsort(d2, axis=1, kind="stable")[:, :k]


def _cloud(seed: int, n: int) -> np.ndarray:
    """Random float points on a noisy cylinder: no two distances tie."""
    rng = np.random.default_rng(seed)
    a, z = rng.uniform(0, 2 * np.pi, n), rng.uniform(0, 2, n)
    xyz = np.column_stack([0.2 * np.cos(a), 0.2 * np.sin(a), z])
    return xyz + rng.normal(0, 0.01, xyz.shape)


@pytest.mark.parametrize("share", [0.97, 0.6, 0.15])
def test_view_reads_equal_brute_force(share: float) -> None:
    """Dense views (most rows read off the table), sparse ones (most rows asked
    afresh, some twice wider): ``knn`` and ``knn_idx`` give the brute-force
    neighbours, and the distances that go with them."""
    xyz = _cloud(int(share * 100), 2500)
    rng = np.random.default_rng(1)
    keep = np.flatnonzero(rng.random(len(xyz)) < share)
    view = NeighbourTable.build(xyz, 24).subset(keep)
    rows = np.sort(rng.choice(len(keep), len(keep) // 3, replace=False))
    sub = xyz[keep]
    for k in (1, 9, 17, 24):
        ref = _brute_knn(sub, k, rows)
        d, i = view.knn(k, rows)
        np.testing.assert_array_equal(i, ref)
        np.testing.assert_array_equal(view.knn_idx(k, rows), ref)
        np.testing.assert_allclose(
            d, np.linalg.norm(sub[rows][:, None] - sub[ref], axis=2), atol=1e-12
        )
    # Every row, and a k above the table's width (a fresh query on the view).
    np.testing.assert_array_equal(
        view.knn_idx(17), _brute_knn(sub, 17, np.arange(len(sub)))
    )
    np.testing.assert_array_equal(view.knn_idx(30, rows), _brute_knn(sub, 30, rows))


def test_index_only_read_equals_the_full_read_on_the_whole_cloud() -> None:
    """On the whole cloud (no view) the index-only read is the table's own columns."""
    xyz = _cloud(7, 1500)
    table = NeighbourTable.build(xyz, 16)
    rows = np.arange(0, len(xyz), 5)
    np.testing.assert_array_equal(table.knn_idx(12, rows), table.knn(12, rows)[1])
    np.testing.assert_array_equal(table.knn_idx(16), table.knn(16)[1])
    np.testing.assert_array_equal(
        table.knn_idx(16), _brute_knn(xyz, 16, np.arange(len(xyz)))
    )


def _merge_before(ranked, centre):  # type: ignore[no-untyped-def]
    """pipeline.sources.merge_same_solutions as it was (every pair compared)."""
    from dataclasses import replace

    from amrst.stages.candidates import CandidateList, distinct_solutions

    kept = []
    for c in ranked.candidates:
        for k, done in enumerate(kept):
            if c.origin not in done.origins and not distinct_solutions(
                c.T_target_source, done.T_target_source, centre
            ):
                kept[k] = replace(done, also_found_by=(*done.also_found_by, *c.origins))
                break
        else:
            kept.append(c)
    kept = [replace(c, rank=r) for r, c in enumerate(kept, start=1)]
    return CandidateList(tuple(kept), ranked.n_matches)


@pytest.mark.parametrize("seed", range(6))
def test_merge_same_solutions_equals_the_pairwise_loop(seed: int) -> None:
    """Candidates of every origin, some poses repeated across origins (and within
    one): the merged list is the one the all-pairs loop gave."""
    from scipy.spatial.transform import Rotation

    from amrst.pipeline.sources import merge_same_solutions
    from amrst.stages.candidates import Candidate, CandidateList, Origin

    rng = np.random.default_rng(seed)
    poses = []
    for _ in range(6):
        T = np.eye(4)
        T[:3, :3] = Rotation.random(random_state=int(rng.integers(1 << 30))).as_matrix()
        T[:3, 3] = rng.normal(0, 3, 3)
        poses.append(T)
    cands = []
    for i in range(40):
        T = poses[int(rng.integers(len(poses)))].copy()
        T[:3, 3] += rng.normal(0, 0.05, 3)  # the same solution, slightly apart
        cands.append(
            Candidate(
                id=i,
                rank=int(rng.integers(1, 50)),
                score=0.5,
                raw_score=0.4,
                support=1,
                volume_m3=1.0,
                edge_error=0.01,
                svd_residual_m=0.01,
                target_idx=np.arange(4),
                source_idx=np.arange(4),
                T_match=T,
                T_target_source=T,
                polished=True,
                explanation="",
                origin=list(Origin)[int(rng.choice(4, p=[0.7, 0.1, 0.1, 0.1]))],
            )
        )
    ranked = CandidateList(tuple(cands), 40)
    centre = np.array([0.3, -0.2, 4.0])
    got, want = merge_same_solutions(ranked, centre), _merge_before(ranked, centre)
    assert [(c.id, c.rank, c.origins) for c in got.candidates] == [
        (c.id, c.rank, c.origins) for c in want.candidates
    ]
    assert len(got.candidates) < len(cands)


def test_analysis_again_with_an_expected_ground_reuses_the_preprocessing() -> None:
    """A scan analysed again for the ground the other scan found (register's second
    pass) keeps its first preprocessing: the same analysis as one made afresh."""
    from amrst.params import RegistrationParams
    from amrst.pipeline import analyse_scan
    from amrst.types import Cloud

    rng = np.random.default_rng(11)
    t, z = rng.uniform(0, 2 * np.pi, 6000), rng.uniform(0, 4, 6000)
    stem = np.column_stack([0.15 * np.cos(t), 0.15 * np.sin(t), z])
    d = rng.normal(size=(6000, 3))
    crown = d / np.linalg.norm(d, axis=1)[:, None] * [1.5, 1.5, 1.0] + [0, 0, 4.5]
    xy = rng.uniform(-3, 3, (8000, 2))
    ground = np.column_stack([xy, 0.1 * xy[:, 0] + rng.normal(0, 0.005, len(xy))])
    cloud = Cloud(np.vstack([stem, crown, ground]) + rng.normal(0, 0.003, (20000, 3)))
    params = RegistrationParams()
    first = analyse_scan(cloud, params)
    assert first.scene_pre is not None
    fresh = analyse_scan(cloud, params, expect_ground=6.0)
    again = analyse_scan(cloud, params, expect_ground=6.0, pre=first.scene_pre)
    assert again.scene_pre is first.scene_pre
    assert again.scene is not None
    assert fresh.scene is not None
    np.testing.assert_array_equal(again.scene.labels, fresh.scene.labels)
    np.testing.assert_array_equal(again.xyz, fresh.xyz)
    np.testing.assert_array_equal(again.is_wood, fresh.is_wood)
    assert again.skeleton is not None
    assert fresh.skeleton is not None
    np.testing.assert_array_equal(again.skeleton.nodes, fresh.skeleton.nodes)


def test_covariances_in_chunks_equal_one_pass_and_the_row_sums(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """More neighbourhoods than one chunk (two boundaries crossed, a short last
    chunk): the same bits as a single pass, and as numpy's per-row sums."""
    from amrst.stages import features

    rng = np.random.default_rng(8)
    xyz = rng.normal(size=(6000, 3)) + np.array([40.0, -3.0, 12.0])
    idx = rng.integers(0, len(xyz), (2 * features.COV_CHUNK + 123, 30))
    chunked = features._covariances(xyz, idx, (10, 30))
    monkeypatch.setattr(features, "COV_CHUNK", 10**9)
    whole = features._covariances(xyz, idx, (10, 30))
    g = xyz.T[:, idx] - xyz.T[:, idx[:, :1]]
    x, y, z = g
    terms = (x, y, z, x * x, y * y, z * z)
    sums = [np.zeros(len(idx))] * 6
    done = 0
    for k, got, one in zip((10, 30), chunked, whole, strict=True):
        # Runs summed per row as the code before summed them (0:10, then 10:30).
        sums = [s + t[:, done:k].sum(axis=1) for s, t in zip(sums, terms, strict=True)]
        done = k
        mean, sq = [v / k for v in sums[:3]], [v / k for v in sums[3:]]
        want = [s - m * m for s, m in zip(sq, mean, strict=True)]
        for a, b, w in zip(got[:3], one[:3], want, strict=True):
            np.testing.assert_array_equal(a, b)
            np.testing.assert_array_equal(a, w)
        for a, b in zip(got[3:], one[3:], strict=True):
            np.testing.assert_array_equal(a, b)
