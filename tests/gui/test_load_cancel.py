"""Opening a big LAS/LAZ pair stops soon after Cancel, the reading too, and
nothing of the half-read files is kept.

The files are generated here (jittered copies of the bundled sample, seeded).
"""

from __future__ import annotations

import sys
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))

from dense_clouds import dense_cloud

# Reading both takes seconds; Cancel comes after the first chunk.
BIG = 3_000_000


@pytest.fixture(scope="module")
def big_laz_pair(tmp_path_factory) -> tuple[Path, Path]:
    from amrst import io

    folder = tmp_path_factory.mktemp("lazpair")
    paths = []
    for seed, role in enumerate(("target", "source")):
        path = folder / f"{role}.laz"
        io.write(path, dense_cloud(BIG, role, seed))
        paths.append(path)
    return paths[0], paths[1]


@pytest.mark.slow
def test_cancel_stops_loading_a_big_pair_and_keeps_nothing(
    make_main_window, qtbot, big_laz_pair
):
    win = make_main_window()
    s = win.session
    loaded: list[str] = []
    s.scan_loaded.connect(loaded.append)
    marks: dict = {}

    def on_progress(_fraction: float, message: str) -> None:
        # Cancel once the first chunk of points was read: mid-file.
        if "job" not in marks and "points read" in message:
            marks["job"] = s.runner.job
            marks["job"].ended.connect(lambda: marks.setdefault("ended", True))
            s.cancel()

    s.progressed.connect(on_progress)
    with qtbot.waitSignal(s.cancelled, timeout=120_000):
        win.open_pair(*big_laz_pair)
    qtbot.waitUntil(lambda: not s.busy, timeout=5_000)
    # The reading itself stops (the worker thread returns), not only the job.
    qtbot.waitUntil(lambda: "ended" in marks, timeout=30_000)
    assert loaded == []
    assert s.cloud("target") is None
    assert s.cloud("source") is None
    # And the same files load in full afterwards.
    with qtbot.waitSignals([s.scan_loaded] * 2, timeout=120_000):
        win.open_pair(*big_laz_pair)
    assert len(s.cloud("target")) == BIG
