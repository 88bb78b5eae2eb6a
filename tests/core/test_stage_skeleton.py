"""Skeleton and key points: a synthetic forked tree with a known fork and tips, and
hand-built skeletons for the depth rule, the merge radius and the weights."""

from __future__ import annotations

import numpy as np
import pytest

from amrst.errors import InvalidInput
from amrst.stages.keypoints import KeypointParams, extract_keypoints
from amrst.stages.skeleton import SkeletonParams, SkeletonResult, build_skeleton

BASE = np.array([0.0, 0.0, 0.0])
FORK = np.array([0.0, 0.0, 3.0])
UP_LEFT = np.array([-np.sin(np.pi / 4), 0.0, np.cos(np.pi / 4)])
UP_RIGHT = np.array([np.sin(np.pi / 4), 0.0, np.cos(np.pi / 4)])
TIP_LEFT = FORK + 2.0 * UP_LEFT
TIP_RIGHT = FORK + 2.0 * UP_RIGHT


def _cylinder_surface(a, b, radius, n, rng) -> np.ndarray:
    d = (b - a) / np.linalg.norm(b - a)
    u = np.cross(d, [1.0, 0, 0] if abs(d[0]) < 0.9 else [0, 1.0, 0])
    u /= np.linalg.norm(u)
    v = np.cross(d, u)
    s = rng.uniform(0, np.linalg.norm(b - a), n)
    phi = rng.uniform(0, 2 * np.pi, n)
    return (
        a
        + s[:, None] * d
        + radius * (np.cos(phi)[:, None] * u + np.sin(phi)[:, None] * v)
    )


@pytest.fixture(scope="module")
def forked_tree() -> np.ndarray:
    """Trunk 0..3 m and two 2 m branches forking at 3 m (up-left, up-right), sampled
    densely (about 1 cm) on 3 cm cylinders."""
    rng = np.random.default_rng(0)
    return np.vstack(
        [
            _cylinder_surface(BASE, FORK, 0.03, 6000, rng),
            _cylinder_surface(FORK, TIP_LEFT, 0.03, 4000, rng),
            _cylinder_surface(FORK, TIP_RIGHT, 0.03, 4000, rng),
        ]
    )


def assert_is_rooted_tree(skel: SkeletonResult) -> None:
    """Exactly one root, every parent a valid node, every node reaches the root."""
    k = len(skel.nodes)
    assert skel.parent.shape == (k,)
    assert np.flatnonzero(skel.parent < 0).tolist() == [skel.root]
    assert np.all(skel.parent < k)
    for node in range(k):
        seen, cur = set(), node
        while cur != skel.root:
            assert cur not in seen, f"cycle through node {cur}"
            seen.add(cur)
            cur = int(skel.parent[cur])
            assert cur >= 0, f"node {node} does not reach the root"
    assert len(skel.edges) == k - 1


def _nearest(points: np.ndarray, target: np.ndarray) -> float:
    return (
        float(np.min(np.linalg.norm(points - target, axis=1)))
        if len(points)
        else np.inf
    )


def test_forked_tree_gives_root_fork_and_tips(forked_tree) -> None:
    pts = forked_tree.copy()
    pts.setflags(write=False)
    skel = build_skeleton(pts, SkeletonParams())
    np.testing.assert_array_equal(pts, forked_tree)
    assert_is_rooted_tree(skel)
    assert skel.n_components_bridged == 0
    assert np.linalg.norm(skel.nodes[skel.root] - BASE) < 0.3
    assert skel.geodesic_m[skel.root] == 0.0
    # Geodesic distance grows from parent to child, and nodes follow the wood.
    child = skel.edges[:, 1]
    assert np.all(skel.geodesic_m[child] > skel.geodesic_m[skel.parent[child]])
    assert skel.n_points.sum() > 0
    # Exactly one branch point (the fork) and two end points (the tips).
    assert np.count_nonzero(skel.children_count >= 2) == 1
    assert np.count_nonzero(skel.children_count == 0) == 2

    kp = extract_keypoints(skel, KeypointParams())
    assert sorted(kp.kind.tolist()) == ["branch", "end", "end", "root"]
    assert _nearest(kp.xyz[kp.kind == "branch"], FORK) < 0.3
    ends = kp.xyz[kp.kind == "end"]
    assert _nearest(ends, TIP_LEFT) < 0.3
    assert _nearest(ends, TIP_RIGHT) < 0.3
    assert _nearest(kp.xyz[kp.kind == "root"], BASE) < 0.3
    assert kp.weight[0] == 1.0  # the root is the heaviest (geodesic 0)


def test_gap_in_a_branch_is_bridged(forked_tree) -> None:
    """Cut a 20 cm slice out of the right branch (wider than any kNN edge there):
    the part beyond the gap is bridged back, so its tip stays in the skeleton."""
    rel = forked_tree - FORK
    along = rel @ UP_RIGHT
    on_right = (np.linalg.norm(rel - np.outer(along, UP_RIGHT), axis=1) < 0.05) & (
        along > 0
    )
    cut = on_right & (along > 1.0) & (along < 1.2)
    assert cut.sum() > 300
    pts = forked_tree[~cut]
    skel = build_skeleton(pts, SkeletonParams())
    assert_is_rooted_tree(skel)
    assert skel.n_components_bridged >= 1
    assert _nearest(skel.nodes, TIP_RIGHT) < 0.3
    kp = extract_keypoints(skel, KeypointParams())
    assert _nearest(kp.xyz[kp.kind == "end"], TIP_RIGHT) < 0.3
    assert _nearest(kp.xyz[kp.kind == "end"], TIP_LEFT) < 0.3


def test_sample_skeletons_are_rooted_trees(sample_run) -> None:
    """The same structural check on the skeletons of the real sample scans."""
    for scan in (sample_run.result.target, sample_run.result.source):
        assert_is_rooted_tree(scan.skeleton)
        assert len(scan.skeleton.nodes) > 20


def test_too_few_points_raise_invalid_input() -> None:
    pts = np.random.default_rng(0).uniform(0, 1, (30, 3))
    with pytest.raises(InvalidInput, match="Only 30 wood points"):
        build_skeleton(pts, SkeletonParams(min_points=50))


# --- key points on hand-built skeletons ----------------------------------------------


def _binary_skeleton(levels: int, chain: int = 2) -> SkeletonResult:
    """A root, a trunk chain, then a full binary tree of ``levels`` fork levels.

    Every segment between key nodes has ``chain`` plain (one-child) nodes, 1 m apart
    along the path, so key node depths are: root 1, first fork 2, next forks 3, ...
    """
    nodes, parent, geo = [np.zeros(3)], [-1], [0.0]

    def add_segment(start: int, direction: np.ndarray) -> int:
        cur = start
        for _ in range(chain + 1):
            nodes.append(nodes[cur] + direction)
            parent.append(cur)
            geo.append(geo[cur] + float(np.linalg.norm(direction)))
            cur = len(nodes) - 1
        return cur

    tips = [add_segment(0, np.array([0.0, 0.0, 1.0]))]  # first fork
    for level in range(levels):
        new = []
        for i, tip in enumerate(tips):
            for side in (-1.0, 1.0):
                spread = 1.0 / (level + 1)
                d = np.array([side * spread, (i % 2) * 0.3, 1.0])
                new.append(add_segment(tip, d / np.linalg.norm(d)))
        tips = new
    k = len(nodes)
    return SkeletonResult(
        nodes=np.asarray(nodes),
        parent=np.asarray(parent, dtype=np.int64),
        geodesic_m=np.asarray(geo),
        n_points=np.ones(k, dtype=np.int64),
        root=0,
        n_components_bridged=0,
    )


def test_depth_rule_keeps_the_first_key_nodes_on_each_path() -> None:
    skel = _binary_skeleton(levels=5)  # key depths: root 1, forks 2..6, ends 7
    assert_is_rooted_tree(skel)
    wide = {"merge_radius_m": 0.0, "max_keypoints": 200}
    kp2 = extract_keypoints(skel, KeypointParams(max_depth=2, **wide))
    kp5 = extract_keypoints(skel, KeypointParams(max_depth=5, **wide))
    kp50 = extract_keypoints(skel, KeypointParams(max_depth=50, **wide))
    # Depth 2: the root and the first fork. Depth 5: + 2 + 4 + 8 forks.
    assert sorted(kp2.kind.tolist()) == ["branch", "root"]
    assert len(kp5.xyz) == 1 + 1 + 2 + 4 + 8
    assert set(kp5.depth.tolist()) == {1, 2, 3, 4, 5}
    assert np.all(kp5.kind[kp5.depth > 1] == "branch")
    # All: root + 31 forks + 32 ends.
    assert len(kp50.xyz) == 1 + 31 + 32
    assert np.count_nonzero(kp50.kind == "end") == 32
    assert len(kp2.xyz) < len(kp5.xyz) < len(kp50.xyz)
    # Only key nodes are chosen: plain chain nodes (one child) never appear.
    assert np.all(skel.children_count[kp50.node[kp50.kind != "root"]] != 1)


def test_merge_radius_merges_near_duplicates_keeping_the_heavier() -> None:
    # Root -> 1 m trunk -> fork; two end points 10 cm apart, one nearer the root.
    nodes = np.array(
        [[0, 0, 0], [0, 0, 1], [0, 0, 2], [0.05, 0, 3], [-0.05, 0, 3.0], [0, 0, 2.5]]
    )
    parent = np.array([-1, 0, 1, 2, 5, 2])
    geo = np.array([0.0, 1.0, 2.0, 3.0, 3.6, 2.5])
    skel = SkeletonResult(nodes, parent, geo, np.ones(6, np.int64), 0, 0)
    assert_is_rooted_tree(skel)
    apart = extract_keypoints(skel, KeypointParams(merge_radius_m=0.05))
    merged = extract_keypoints(skel, KeypointParams(merge_radius_m=0.3))
    assert sorted(apart.node.tolist()) == [0, 2, 3, 4]
    assert sorted(merged.node.tolist()) == [0, 2, 3]  # node 4 (farther) merged away
    # Every key point is within 3.5 m of the root: one key point is left.
    assert extract_keypoints(
        skel, KeypointParams(merge_radius_m=3.5)
    ).node.tolist() == [0]


def test_weights_decrease_with_geodesic_distance() -> None:
    skel = _binary_skeleton(levels=3)
    params = KeypointParams(merge_radius_m=0.0, max_keypoints=200, weight_scale_m=4.0)
    kp = extract_keypoints(skel, params)
    geo = skel.geodesic_m[kp.node]
    np.testing.assert_allclose(kp.weight, np.exp(-geo / 4.0))
    assert np.all(np.diff(kp.weight) <= 0), "not heaviest first"
    assert np.all(np.diff(geo) >= 0)
    assert np.all((kp.weight > 0) & (kp.weight <= 1))
    np.testing.assert_array_equal(kp.xyz, skel.nodes[kp.node])
    # max_keypoints keeps the heaviest ones.
    few = extract_keypoints(skel, KeypointParams(merge_radius_m=0.0, max_keypoints=4))
    np.testing.assert_array_equal(few.node, kp.node[:4])
