"""Messages between the app and its engine process (``engine_process``), no Qt.

A message is one pickled object (protocol 5) in a frame: an 8-byte length and
the pickle, then the count of out-of-band buffers and each buffer with its
length. numpy arrays travel out of band, written straight from their memory and
read straight into the memory of the array that is rebuilt (no copy in pickle).

Big arrays are sent once. Each side keeps an :class:`ArrayCache`: an array of at
least ``BIG_BYTES`` that crossed the pipe, in either direction, has a token on
both sides, and later messages name it by its token. So a scan of ten million
points crosses once, when the first step needs it, and the analyses every step
hands back name it instead of carrying it again. The app keeps the arrays weakly
(what it dropped is gone) and tells the engine, with every call, which tokens it
still holds; the engine drops the others. The app's tokens are even, the
engine's odd, so the two never give the same token to different arrays.
"""

from __future__ import annotations

import io
import pickle
import struct
import weakref
from typing import IO, Any, Protocol

import numpy as np

BIG_BYTES = 1 << 20  # smaller arrays travel inside the pickle every time
_HEAD = struct.Struct("<QI")  # pickle length, buffer count
_LEN = struct.Struct("<Q")
# Written in slices: a pipe write of hundreds of MB in one call is fine, but
# slices let a cancelled reader see the end of the pipe between them.
SLICE = 16 << 20


class Sink(Protocol):
    """Where a message is written: a binary file or the engine's pipe."""

    def write(self, data: Any, /) -> int | None: ...
    def flush(self) -> None: ...


class ArrayCache:
    """Tokens of the arrays both sides hold; ``weak=True`` on the app's side.

    Not thread-safe: each side reads and writes array frames under one lock of
    its own (the app's engine call, the engine's writer). The app's side keeps
    weak references without callbacks (the garbage collector could run one in
    the middle of a frame); dead entries are dropped when next looked at.
    """

    def __init__(self, *, weak: bool, first_token: int) -> None:
        self._weak = weak
        self._next = first_token
        self._by_token: dict[int, Any] = {}  # token -> array or weakref to it
        self._by_id: dict[int, int] = {}  # id(array) -> token

    def token_of(self, arr: np.ndarray) -> int | None:
        """The token of this very array object, if it has one."""
        token = self._by_id.get(id(arr))
        if token is None or self._get(token) is not arr:
            return None
        return token

    def add(self, arr: np.ndarray, token: int | None = None) -> int:
        """Give ``arr`` a token (a new one unless ``token`` is given)."""
        self._purge()
        if token is None:
            token, self._next = self._next, self._next + 2
        self._by_token[token] = weakref.ref(arr) if self._weak else arr
        self._by_id[id(arr)] = token
        return token

    def get(self, token: int) -> np.ndarray:
        """The array of ``token``; KeyError if it is gone."""
        arr = self._get(token)
        if arr is None:
            raise KeyError(f"array {token} is no longer held")
        return arr

    def alive(self) -> dict[int, np.ndarray]:
        """Every array still held, by token (strong references)."""
        self._purge()
        out = {t: self._get(t) for t in list(self._by_token)}
        return {t: a for t, a in out.items() if a is not None}

    def keep_only(self, tokens: set[int]) -> None:
        """Drop every array whose token is not in ``tokens``."""
        for token in [t for t in self._by_token if t not in tokens]:
            self._forget(token)

    def forget(self, tokens: list[int]) -> None:
        """Drop these tokens (arrays given a token but never sent)."""
        for token in tokens:
            self._forget(token)

    def clear(self) -> None:
        """Forget every array (the other side was restarted)."""
        self._by_token.clear()
        self._by_id.clear()

    def _get(self, token: int) -> np.ndarray | None:
        ref = self._by_token.get(token)
        if ref is None:
            return None
        return ref() if self._weak else ref

    def _forget(self, token: int) -> None:
        arr = self._get(token)
        self._by_token.pop(token, None)
        if arr is not None and self._by_id.get(id(arr)) == token:
            del self._by_id[id(arr)]

    def _purge(self) -> None:
        """Drop the entries of arrays that are gone (the app's side)."""
        if not self._weak:
            return
        dead = {t for t, ref in self._by_token.items() if ref() is None}
        if dead:
            for token in dead:
                del self._by_token[token]
            self._by_id = {k: t for k, t in self._by_id.items() if t not in dead}


class _Pickler(pickle.Pickler):
    def __init__(self, file: IO[bytes], cache: ArrayCache, buffers: list) -> None:
        super().__init__(file, protocol=5, buffer_callback=buffers.append)
        self._cache = cache
        self._inner: object = None
        self.added: list[int] = []  # tokens given while pickling this message

    def persistent_id(self, obj: Any) -> Any:
        if type(obj) is not np.ndarray or obj.nbytes < BIG_BYTES:
            return None
        if obj is self._inner:  # the array inside a ("new", ...) id: pickle it
            self._inner = None
            return None
        token = self._cache.token_of(obj)
        if token is not None:
            return ("ref", token)
        self._inner = obj
        self.added.append(self._cache.add(obj))
        return ("new", self.added[-1], obj.flags.writeable, obj)


class _Unpickler(pickle.Unpickler):
    def __init__(self, file: IO[bytes], cache: ArrayCache, buffers: list) -> None:
        super().__init__(file, buffers=buffers)
        self._cache = cache
        self.seen: set[int] = set()

    def persistent_load(self, pid: Any) -> Any:
        self.seen.add(pid[1])
        if pid[0] == "ref":
            return self._cache.get(pid[1])
        _, token, writeable, arr = pid
        if not writeable:
            arr.flags.writeable = False
        self._cache.add(arr, token)
        return arr


def write_message(out: Sink, obj: Any, cache: ArrayCache) -> None:
    """Pickle ``obj`` into ``out`` (a binary file) as one frame, and flush."""
    buffers: list[pickle.PickleBuffer] = []
    body = io.BytesIO()
    pickler = _Pickler(body, cache, buffers)
    try:
        pickler.dump(obj)
    except BaseException:
        # Nothing was sent: the other side must not be named what it never got.
        cache.forget(pickler.added)
        raise
    out.write(_HEAD.pack(body.tell(), len(buffers)))
    out.write(body.getbuffer())
    for buf in buffers:
        raw = buf.raw()
        out.write(_LEN.pack(raw.nbytes))
        for i in range(0, raw.nbytes, SLICE):
            out.write(raw[i : i + SLICE])
    out.flush()


def read_message(
    src: IO[bytes], cache: ArrayCache, seen: set[int] | None = None
) -> Any:
    """Read one frame from ``src``; EOFError if the other side is gone. The
    tokens of the cached arrays it named are added to ``seen``."""
    length, count = _HEAD.unpack(_read_exactly(src, _HEAD.size))
    body = _read_exactly(src, length)
    buffers = []
    for _ in range(count):
        (n,) = _LEN.unpack(_read_exactly(src, _LEN.size))
        buffers.append(_read_exactly(src, n))
    unpickler = _Unpickler(io.BytesIO(body), cache, buffers)
    obj = unpickler.load()
    if seen is not None:
        seen |= unpickler.seen
    return obj


def _read_exactly(src: IO[bytes], n: int) -> bytearray:
    buf = bytearray(n)
    view = memoryview(buf)
    got = 0
    while got < n:
        k = src.readinto(view[got : min(n, got + SLICE)])  # type: ignore[attr-defined]
        if not k:
            raise EOFError("the other process closed the pipe")
        got += k
    return buf
