"""Reading a LAS/LAZ file stops within a second of Cancel, keeping nothing:
the points are decoded in chunks with a cancel check between them.

The file is generated here (jittered copies of the bundled sample, seeded).
"""

from __future__ import annotations

import sys
import threading
from pathlib import Path

import numpy as np
import pytest

from amrst import io
from amrst.errors import Cancelled
from amrst.io.las import CHUNK_POINTS
from amrst.progress import EventReporter

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))

from dense_clouds import dense_cloud

# Big enough that reading it without a check point would take longer than the second
# a Cancel may take.
BIG = 3_000_000


@pytest.fixture(scope="module")
def big_laz(tmp_path_factory) -> Path:
    path = tmp_path_factory.mktemp("laz") / "big.laz"
    io.write(path, dense_cloud(BIG))
    return path


def test_a_chunked_read_is_the_whole_file(tmp_path) -> None:
    cloud = dense_cloud(CHUNK_POINTS * 2 + 123, seed=3)
    path = tmp_path / "c.las"
    io.write(path, cloud)
    fractions: list[float] = []
    back = io.read(path, reporter=EventReporter(lambda f, _m: fractions.append(f)))
    assert len(back) == len(cloud)
    np.testing.assert_allclose(
        back.xyz + back.offset, cloud.xyz + cloud.offset, atol=1e-3
    )
    assert set(back.attributes) == set(cloud.attributes)
    # One progress report per chunk, the last at the end.
    assert len(fractions) == 3
    assert fractions[-1] == 1.0


@pytest.mark.slow
def test_cancel_stops_a_laz_read_at_its_next_chunk(big_laz) -> None:
    started = threading.Event()
    read_so_far: list[float] = []
    reporter = EventReporter(lambda f, _m: (read_so_far.append(f), started.set()))
    outcome: dict = {}

    def read() -> None:
        try:
            outcome["cloud"] = io.read(big_laz, reporter=reporter)
        except Cancelled as exc:
            outcome["cancelled"] = exc

    worker = threading.Thread(target=read)
    worker.start()
    assert started.wait(60), "no chunk was ever read"
    reporter.cancel()
    at_cancel = len(read_so_far)
    worker.join(30)
    assert "cancelled" in outcome
    assert "cloud" not in outcome
    assert len(read_so_far) - at_cancel <= 1  # the chunk being read, no more
    assert max(read_so_far) < 1.0


class _InterruptedStream:
    """A file whose first write of points gets Ctrl+C while lazrs's callback is in
    it (the header's writes are small and come from Python)."""

    def __init__(self, raw) -> None:
        self.raw = raw
        self.writes = 0

    def write(self, data) -> int:
        import os
        import signal

        if len(data) > 1000 and not self.writes:
            self.writes += 1
            os.kill(os.getpid(), signal.SIGINT)
        return self.raw.write(data)

    def __getattr__(self, name):
        return getattr(self.raw, name)


def test_ctrl_c_during_a_laz_write_stops_it_as_ctrl_c(tmp_path, monkeypatch) -> None:
    """Ctrl+C inside lazrs's write callback is Ctrl+C, not a failed write."""
    import laspy

    real_open = laspy.open

    def interrupted(path, **kwargs):
        return real_open(_InterruptedStream(Path(path).open("wb")), **kwargs)

    monkeypatch.setattr(laspy, "open", interrupted)
    with pytest.raises(KeyboardInterrupt):
        io.write(tmp_path / "plot.laz", dense_cloud(200_000))


def test_a_write_that_fails_after_ctrl_c_reports_the_ctrl_c() -> None:
    import os
    import signal

    from amrst.io.las_write import _ctrl_c_between_chunks

    def full_disk_after_ctrl_c() -> None:
        with _ctrl_c_between_chunks():
            os.kill(os.getpid(), signal.SIGINT)  # held
            raise OSError("No space left on device")

    with pytest.raises(KeyboardInterrupt):
        full_disk_after_ctrl_c()
    assert signal.getsignal(signal.SIGINT) is signal.default_int_handler
