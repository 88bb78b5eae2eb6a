"""KISS-Matcher on one thread, so that its pose is the same on every run.

KISS-Matcher parallelises its features and matching with oneTBB and its max-clique
pruning with OpenMP; with more than one thread its correspondences come out in a
varying order and its pose can differ from run to run. Its Python API has no thread
setting and TBB reads no environment variable for one; the only control is the C++
``tbb::global_control``. :func:`kiss_one_thread` therefore creates one through TBB's
binary interface (``tbb::detail::r1::create``/``destroy``, stable across oneTBB
2021+) on the TBB copy the kiss_matcher wheel loaded, around the call only, and
holds OpenMP to one thread (threadpoolctl) there too. This is the one place the
engine reaches into a library's threads; it goes when KISS-Matcher takes a thread
count.
"""

from __future__ import annotations

import contextlib
import ctypes
import functools
from pathlib import Path
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from collections.abc import Iterator

_CREATE = "_ZN3tbb6detail2r16createERNS0_2d114global_controlE"
_DESTROY = "_ZN3tbb6detail2r17destroyERNS0_2d114global_controlE"
_MAX_ALLOWED_PARALLELISM = 0  # tbb::global_control::max_allowed_parallelism


class _GlobalControl(ctypes.Structure):
    """``tbb::detail::d1::global_control``: value, reserved, parameter."""

    _fields_ = (
        ("value", ctypes.c_size_t),
        ("reserved", ctypes.c_ssize_t),
        ("param", ctypes.c_int),
    )


def _kiss_tbb() -> Path | None:
    """Return the TBB library the kiss_matcher wheel ships (None: not found)."""
    import kiss_matcher

    pkg = Path(kiss_matcher.__file__).resolve().parent
    # auditwheel (Linux) puts it next to the package, delocate (macOS) inside it
    for folder, pattern in (
        (pkg.parent / "kiss_matcher.libs", "libtbb*.so*"),
        (pkg / ".dylibs", "libtbb*.dylib"),
    ):
        found = sorted(folder.glob(pattern))
        if found:
            return found[0]
    return None


@functools.cache
def _tbb() -> Any:
    """Return kiss_matcher's TBB library (None: not found or an unknown interface)."""
    path = _kiss_tbb()
    if path is None:
        return None
    try:
        lib = ctypes.CDLL(str(path))
        getattr(lib, _CREATE), getattr(lib, _DESTROY)
    except (OSError, AttributeError):
        return None
    return lib


@contextlib.contextmanager
def kiss_one_thread() -> Iterator[None]:
    """Run the enclosed KISS-Matcher calls on one TBB and one OpenMP thread.

    The TBB limit lives only as long as the block (a ``global_control`` created on
    entry and destroyed on exit), so other KISS-Matcher calls in the process, such
    as the benchmark's peer, keep their default threads. Without kiss_matcher's TBB
    (another wheel layout) KISS-Matcher runs on its default threads.
    """
    from threadpoolctl import threadpool_limits

    lib = _tbb()
    control = _GlobalControl(1, 0, _MAX_ALLOWED_PARALLELISM)
    if lib is not None:
        getattr(lib, _CREATE)(ctypes.byref(control))
    try:
        with threadpool_limits(limits=1, user_api="openmp"):
            yield
    finally:
        if lib is not None:
            getattr(lib, _DESTROY)(ctypes.byref(control))
