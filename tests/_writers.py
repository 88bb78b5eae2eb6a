"""Writers for test fixtures: the multi-scan formats amrst only reads (E57, PTX), and
another run writing an output folder meanwhile.

Shared by the engine's and the app's tests; imported as ``_writers`` (this folder is
on ``sys.path`` because it holds ``conftest.py``).
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from amrst.files.atomic import write_atomic, write_text_atomic
from amrst.io.e57 import _COLOURS

if TYPE_CHECKING:
    from collections.abc import Callable, Sequence
    from pathlib import Path

    from amrst.types import Cloud, Transform


def write_e57(
    path: str | Path,
    scans: Sequence[Cloud],
    poses: Sequence[Transform] | None = None,
) -> None:
    """Write scans and their poses to one E57 file, atomically.

    Parameters
    ----------
    path : path
        The ``.e57`` file to write.
    scans : sequence of Cloud
        Each scan in its scanner's frame. A scan's ``offset`` is folded into its pose,
        so the points are stored small (pye57 stores them as float32) and
        georeferenced coordinates keep millimetres.
    poses : sequence of (4, 4) float64, optional
        ``T_world_scanner`` of each scan; identity when None.
    """
    from scipy.spatial.transform import Rotation

    from amrst.extras import require

    pye57 = require("pye57", "writing E57 files")
    poses = [np.eye(4)] * len(scans) if poses is None else list(poses)

    def write_to(tmp: Path) -> None:
        tmp.unlink(missing_ok=True)
        with pye57.E57(str(tmp), mode="w") as e57:
            for k, (scan, pose) in enumerate(zip(scans, poses, strict=True)):
                T = np.asarray(pose, np.float64).copy()
                T[:3, 3] += T[:3, :3] @ scan.offset  # offset into the pose
                data: dict[str, np.ndarray] = {
                    f"cartesian{a}": np.ascontiguousarray(scan.xyz[:, i])
                    for i, a in enumerate("XYZ")
                }
                if scan.intensity is not None:
                    data["intensity"] = scan.intensity.astype(np.float32)
                if all(c in scan.attributes for _, c in _COLOURS):
                    for field, name in _COLOURS:
                        data[field] = np.asarray(scan.attributes[name]).astype(np.uint8)
                x, y, z, w = Rotation.from_matrix(T[:3, :3]).as_quat()
                e57.write_scan_raw(
                    data,
                    name=scan.name or f"scan {k}",
                    rotation=np.array([w, x, y, z]),
                    translation=T[:3, 3],
                )

    write_atomic(path, write_to)


def write_ptx(
    path: str | Path,
    scans: Sequence[Cloud],
    poses: Sequence[Transform] | None = None,
) -> None:
    """Write scans with their poses to one PTX file (one row per scan), atomically.

    Each scan's ``offset`` is folded into its pose, so the point lines stay small.
    """
    poses = [np.eye(4)] * len(scans) if poses is None else list(poses)
    parts = []
    for scan, pose in zip(scans, poses, strict=True):
        T = np.asarray(pose, np.float64).copy()
        T[:3, 3] += T[:3, :3] @ scan.offset
        head = [f"{len(scan)}", "1", " ".join(f"{v:.17g}" for v in T[:3, 3])]
        head += [" ".join(f"{v:.17g}" for v in T[:3, k]) for k in range(3)]
        head += [" ".join(f"{v:.17g}" for v in row) for row in T.T]
        cols = [scan.xyz[:, 0], scan.xyz[:, 1], scan.xyz[:, 2]]
        inten = scan.intensity
        cols.append(np.full(len(scan), 0.5) if inten is None else inten)
        fmt = "%.17g %.17g %.17g %.9g"
        if all(c in scan.attributes for c in ("red", "green", "blue")):
            cols += [np.asarray(scan.attributes[c]) for c in ("red", "green", "blue")]
            fmt += " %d %d %d"
        body = "\n".join(fmt % row for row in zip(*cols, strict=True))
        parts.append("\n".join(head) + "\n" + body + "\n")
    write_text_atomic(path, "".join(parts))


def written_first(func: Callable, path: Path, text: str) -> Callable:
    """Return ``func`` that first writes ``text`` to ``path``: another run writing the
    output folder while the run under test works."""

    def wrapped(*args, **kwargs):
        path.parent.mkdir(exist_ok=True)
        path.write_text(text)
        return func(*args, **kwargs)

    return wrapped
