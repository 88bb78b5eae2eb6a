"""Property-based fuzzing of every reader.

Valid files of each format are cut short, have bytes of their header replaced or
their text re-encoded; whatever hypothesis draws, ``io.read`` either returns a
Cloud or raises InvalidInput/AmrstError, within seconds. Kept small for CI:
a few dozen examples per format, no deadline (the first call imports laspy).
"""

from __future__ import annotations

import functools
import os
import tempfile
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from amrst import io
from amrst.errors import AmrstError
from amrst.types import Cloud

_FORMATS = [".las", ".laz", ".ply", ".pcd", ".xyz", ".csv"]
_SETTINGS = settings(
    max_examples=int(os.environ.get("AMRST_FUZZ_EXAMPLES", "40")),
    deadline=None,
    suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow],
)


@functools.cache
def _valid(ext: str, binary: bool = True) -> bytes:
    rng = np.random.default_rng(11)
    cloud = Cloud(
        rng.uniform(-5, 5, (60, 3)),
        np.array([500000.0, 5000000.0, 250.0]),
        {"intensity": rng.integers(0, 900, 60).astype(np.uint16)},
    )
    with tempfile.TemporaryDirectory() as folder:
        path = Path(folder) / f"v{ext}"
        io.write(path, cloud, binary=binary)
        return path.read_bytes()


def _read_bytes(data: bytes, ext: str) -> None:
    fd, name = tempfile.mkstemp(suffix=ext)
    try:
        with os.fdopen(fd, "wb") as f:
            f.write(data)
        try:
            cloud = io.read(name)
        except AmrstError:  # InvalidInput is one: a clear refusal is fine
            return
        assert np.isfinite(cloud.xyz).all()
    finally:
        os.unlink(name)


@pytest.mark.timeout(300)
@pytest.mark.parametrize("ext", _FORMATS)
@_SETTINGS
@given(data=st.data())
def test_truncated_files(ext, data):
    valid = _valid(ext)
    cut = data.draw(st.integers(0, len(valid)), label="cut")
    _read_bytes(valid[:cut], ext)


@pytest.mark.timeout(300)
@pytest.mark.parametrize("ext", _FORMATS)
@_SETTINGS
@given(data=st.data())
def test_header_bytes_replaced(ext, data):
    valid = bytearray(_valid(ext))
    head = min(len(valid), 400)  # the header (LAS: 227-375 bytes, text: a line)
    for _ in range(data.draw(st.integers(1, 8), label="n_changes")):
        pos = data.draw(st.integers(0, head - 1), label="pos")
        valid[pos] = data.draw(st.integers(0, 255), label="byte")
    _read_bytes(bytes(valid), ext)


@pytest.mark.timeout(300)
@pytest.mark.parametrize("ext", [".las", ".laz"])
@_SETTINGS
@given(data=st.data())
def test_las_header_fields(ext, data):
    """Counts, offsets and sizes of the LAS header set to any 32-bit value."""
    import struct

    valid = bytearray(_valid(ext))
    fields = {94: "<H", 96: "<I", 100: "<I", 104: "<B", 105: "<H", 107: "<I"}
    pos = data.draw(st.sampled_from(sorted(fields)), label="field")
    fmt = fields[pos]
    top = 2 ** (8 * struct.calcsize(fmt)) - 1
    struct.pack_into(fmt, valid, pos, data.draw(st.integers(0, top), label="value"))
    _read_bytes(bytes(valid), ext)


@pytest.mark.timeout(300)
@pytest.mark.parametrize("ext", [".ply", ".pcd", ".xyz"])
@_SETTINGS
@given(
    encoding=st.sampled_from(["utf-16", "utf-32", "latin-1", "utf-8-sig", "cp1252"]),
    noise=st.text(max_size=30),
    at=st.integers(0, 2000),
)
def test_ascii_files_in_other_encodings_with_noise(ext, encoding, noise, at):
    text = _valid(ext, binary=False).decode("ascii")
    text = text[:at] + noise + text[at:]
    _read_bytes(text.encode(encoding, errors="replace"), ext)
