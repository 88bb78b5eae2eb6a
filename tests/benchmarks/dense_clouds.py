"""Big clouds for the app's speed tests and benchmark, generated, never shipped.

``dense_cloud(n)`` makes ``n`` points from jittered copies of the bundled sample's
target scan (or any base cloud): every copy moves each point by a seeded Gaussian
jitter (3 mm by default), so the tree keeps its shape and its scanner-like density
grows with ``n``, as a finer scan of the same tree would. Intensity goes along.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[2]
SAMPLE = ROOT / "resources" / "sample"


def dense_xyz(
    base: np.ndarray, n: int, seed: int = 0, jitter_m: float = 0.003
) -> np.ndarray:
    """(n, 3) float64: ``base`` (M, 3) repeated and jittered, seeded."""
    rng = np.random.default_rng(seed)
    reps = -(-n // len(base))
    xyz = np.tile(np.asarray(base, np.float64), (reps, 1))[:n]
    # float32 noise added in place keeps the peak memory near one float64 copy.
    xyz += rng.standard_normal((n, 3), dtype=np.float32) * np.float32(jitter_m)
    return xyz


def dense_cloud(n: int, role: str = "target", seed: int = 0):
    """An ``amrst.types.Cloud`` of ``n`` points made from the sample's ``role`` scan."""
    from amrst import io
    from amrst.types import Cloud

    base = io.read(SAMPLE / f"{role}.ply")
    reps = -(-n // len(base))
    attrs = {
        k: np.tile(v, (reps,) + (1,) * (v.ndim - 1))[:n]
        for k, v in base.attributes.items()
    }
    xyz = dense_xyz(base.xyz, n, seed)
    return Cloud(xyz, base.offset, attrs, name=f"dense_{role}_{n}")


def write_dense_pair(folder: Path, n_target: int, n_source: int, seed: int = 0):
    """Write ``target.ply`` and ``source.ply`` (binary) of the given sizes; paths."""
    from amrst import io

    folder.mkdir(parents=True, exist_ok=True)
    paths = []
    for role, n, s in (("target", n_target, seed), ("source", n_source, seed + 1)):
        path = folder / f"{role}_{n}.ply"
        if not path.is_file():
            io.write(path, dense_cloud(n, role, s))
        paths.append(path)
    return tuple(paths)
