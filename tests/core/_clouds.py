"""Small clouds and file headers shared by the io tests."""

from __future__ import annotations

import numpy as np

from amrst.types import Cloud

# A georeferenced offset (UTM-like metres) for clouds that must keep millimetres.
GEO_OFFSET = np.array([500000.0, 5000000.0, 250.0])


def small_cloud() -> Cloud:
    """200 random points within 5 m of the origin, with a 'wood' attribute."""
    rng = np.random.default_rng(3)
    return Cloud(
        rng.uniform(-5, 5, (200, 3)), attributes={"wood": np.ones(200, np.uint8)}
    )


def ply_header(fmt: str, n: int, props: str, extra: str = "") -> bytes:
    """The header of a PLY file with ``n`` vertices of the given property lines."""
    return (
        f"ply\nformat {fmt} 1.0\ncomment hand made\nelement vertex {n}\n{props}"
        f"{extra}end_header\n"
    ).encode()
