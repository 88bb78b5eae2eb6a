"""Key points: branch points and end points of the skeleton, with the paper's depth rule.

Paper section II.D.1: branch points (nodes with several children), end points (no child)
and the root; along each root-to-end path only the first ``max_depth`` of these key nodes
are kept, which favours the trunk and main branches that both scans see alike. Key points
near the trunk get a higher weight than far tips, which differ most between scans.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    from amrst.stages.skeleton import SkeletonResult


@dataclass(frozen=True, slots=True, kw_only=True)
class KeypointParams:
    """Key point selection."""

    max_depth: int = field(
        default=50,
        metadata={
            "unit": "key nodes",
            "min": 1,
            "max": 50,
            "help": "Depth rule: keep the first N key nodes on each root-to-end path (paper: 5).",
        },
    )
    min_children: int = field(
        default=2,
        metadata={
            "unit": "children",
            "min": 2,
            "max": 5,
            "help": "A node with at least this many children is a branch point.",
        },
    )
    merge_radius_m: float = field(
        default=0.3,
        metadata={
            "unit": "m",
            "min": 0.0,
            "max": 5.0,
            "help": "Key points closer than this are merged into one (removes near-duplicates).",
        },
    )
    max_keypoints: int = field(
        default=32,
        metadata={
            "unit": "points",
            "min": 4,
            "max": 200,
            "help": "At most this many key points (highest weight first) go to matching.",
        },
    )
    weight_scale_m: float = field(
        default=8.0,
        metadata={
            "unit": "m",
            "min": 0.1,
            "max": 100.0,
            "help": "Weight = exp(-geodesic distance from the root / this); near-trunk points rank first.",
        },
    )


@dataclass(frozen=True, slots=True)
class KeypointResult:
    """Key points of one skeleton, highest weight first."""

    xyz: np.ndarray  # (M, 3) float64
    kind: np.ndarray  # (M,) str: "root", "branch" or "end"
    weight: np.ndarray  # (M,) float64 in (0, 1]
    node: np.ndarray  # (M,) int64 skeleton node of each key point
    depth: np.ndarray  # (M,) int64 key-node depth along its path (root = 1)


def extract_keypoints(
    skeleton: SkeletonResult, params: KeypointParams
) -> KeypointResult:
    """Branch, end and root points of a skeleton, filtered by the depth rule.

    Parameters
    ----------
    skeleton : SkeletonResult
    params : KeypointParams

    Returns
    -------
    KeypointResult
    """
    parent = skeleton.parent
    children = skeleton.children_count
    is_key = (children >= params.min_children) | (children == 0) | (parent < 0)
    # Key depth of each node: number of key nodes on the path root..node (parents first).
    order = np.argsort(skeleton.geodesic_m, kind="stable")
    depth = np.zeros(len(parent), dtype=np.int64)
    for node in order:
        p = parent[node]
        depth[node] = (depth[p] if p >= 0 else 0) + int(is_key[node])
    sel = np.flatnonzero(is_key & (depth <= params.max_depth))
    kind = np.where(
        parent[sel] < 0, "root", np.where(children[sel] == 0, "end", "branch")
    )
    weight = np.exp(-skeleton.geodesic_m[sel] / params.weight_scale_m)
    # Heaviest first, then merge near-duplicates greedily (keep the heavier one).
    order = np.argsort(-weight, kind="stable")
    sel, kind, weight = sel[order], kind[order], weight[order]
    xyz = skeleton.nodes[sel]
    kept: list[int] = []
    for i in range(len(sel)):
        if params.merge_radius_m > 0 and kept:
            d = np.linalg.norm(xyz[kept] - xyz[i], axis=1)
            if d.min() < params.merge_radius_m:
                continue
        kept.append(i)
        if len(kept) >= params.max_keypoints:
            break
    k = np.asarray(kept, dtype=np.int64)
    return KeypointResult(xyz[k], kind[k], weight[k], sel[k], depth[sel][k])
