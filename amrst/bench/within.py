"""The share of source points near the target under a transform (the truth check)."""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from amrst.types import apply_transform

if TYPE_CHECKING:
    from collections.abc import Sequence

NAN = float("nan")
WITHIN_M = (0.02, 0.04)
WITHIN_POINTS = 20_000


def within_fractions(
    target_xyz: np.ndarray, source_xyz: np.ndarray, transforms: Sequence[np.ndarray]
) -> list[tuple[float, ...]]:
    """Compute the share of source points near the target under each transform.

    One share per WITHIN_M distance; the source points are a seeded sample of at most
    WITHIN_POINTS.
    """
    from scipy.spatial import cKDTree

    if len(target_xyz) == 0 or len(source_xyz) == 0:
        return [(NAN,) * len(WITHIN_M) for _ in transforms]
    src = source_xyz
    if len(src) > WITHIN_POINTS:
        rng = np.random.default_rng(0)
        src = src[rng.choice(len(src), WITHIN_POINTS, replace=False)]
    tree = cKDTree(target_xyz)
    out = []
    for T in transforms:
        d = tree.query(
            apply_transform(T, src), distance_upper_bound=max(WITHIN_M), workers=-1
        )[0]
        out.append(tuple(float(np.mean(d < r)) for r in WITHIN_M))
    return out
