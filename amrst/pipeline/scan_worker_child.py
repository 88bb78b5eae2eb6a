"""The scan worker's side (see ``scan_worker``): its loop, and what it sends back.

Messages both ways are a length (:data:`HEAD`), then a pickle. A request is
``(seq, source cloud, params, stem)``; every answer frame is ``(kind, seq, value)``:
``progress`` and ``log`` frames while the scan is analysed (each small enough to
be written whole or dropped when the pipe is full: the parent reads them only once
its own scan is done), then one ``result`` or ``error``.
"""

from __future__ import annotations

import contextlib
import logging
import os
import pickle
import signal
import struct
import traceback
from dataclasses import replace
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from amrst.params import RegistrationParams
    from amrst.types import Cloud

HEAD = struct.Struct("<Q")
_SMALL = 4000  # under PIPE_BUF (4096 on Linux): a write of it is whole or nothing


def write_all(fd: int, data: bytes) -> None:
    """Write a length and ``data`` to a blocking ``fd``."""
    view = memoryview(HEAD.pack(len(data)) + data)
    while view:
        view = view[os.write(fd, view) :]


def serve(requests: int, answers: int) -> None:
    """Serve one source scan per request until the input ends (the worker's loop).

    Never returns: the process ends with ``os._exit`` (no atexit handlers, no
    flushing of the parent's buffers).
    """
    code = 1
    try:
        signal.signal(signal.SIGINT, signal.SIG_IGN)  # Ctrl-C: the parent kills it
        signal.signal(signal.SIGTERM, signal.SIG_DFL)  # not the caller's handler
        signal.pthread_sigmask(signal.SIG_UNBLOCK, {signal.SIGINT})
        from amrst.neighbours import set_threads

        set_threads(1)  # the parent's OpenMP threads are not here (scan_worker)
        _log_to(answers)
        reader = os.fdopen(requests, "rb")
        while True:
            head = reader.read(HEAD.size)
            if len(head) < HEAD.size:
                code = 0
                break
            seq, cloud, params, stem = pickle.loads(reader.read(HEAD.unpack(head)[0]))
            _answer(answers, seq, cloud, params, stem)
    finally:
        os._exit(code)


def _answer(
    fd: int, seq: int, cloud: Cloud, params: RegistrationParams, stem: Any
) -> None:
    from amrst.pipeline.analysis import analyse_scan

    _Frames.seq = seq
    try:
        an = analyse_scan(cloud, params, _PipeReporter(fd), stem)
        pre = replace(an.pre, neighbours=None)
        scene_pre = an.scene_pre and replace(an.scene_pre, neighbours=None)
        # In transit only: the parent puts its own cloud back.
        out = replace(an, pre=pre, scene_pre=scene_pre, cloud=None)  # type: ignore[arg-type]
        data = pickle.dumps(("result", seq, out), protocol=pickle.HIGHEST_PROTOCOL)
    except Exception as exc:  # raised in the parent
        data = pickle.dumps(("error", seq, portable_error(exc)))
    os.set_blocking(fd, True)
    write_all(fd, data)


def portable_error(exc: BaseException) -> BaseException:
    """``exc``, or the nearest class of it that survives pickling, with its message.

    An error the parent cannot rebuild (a class whose ``__init__`` takes other
    arguments, an attribute that does not pickle) would arrive as another error.
    The worker's traceback goes along as ``__traceback_text__`` (as the app's
    workers keep theirs).
    """
    text = "".join(traceback.format_exception(exc))
    for candidate in _candidates(exc):
        try:
            back = pickle.loads(pickle.dumps(candidate))
        except Exception:
            continue
        if isinstance(back, BaseException):
            with contextlib.suppress(AttributeError):
                back.__traceback_text__ = text  # type: ignore[attr-defined]
            return back
    return RuntimeError(f"source scan: {exc}")


def _candidates(exc: BaseException) -> list[BaseException]:
    out: list[BaseException] = [exc]
    for cls in type(exc).__mro__:
        if isinstance(cls, type) and issubclass(cls, BaseException):
            with contextlib.suppress(Exception):
                out.append(cls(str(exc)))
    return out


class _Frames:
    """Small frames (progress, log records), written whole or not at all."""

    seq = 0  # the request being answered

    @classmethod
    def put(cls, fd: int, kind: str, value: object) -> None:
        data = pickle.dumps((kind, cls.seq, value))
        if len(data) + HEAD.size > _SMALL:
            return
        os.set_blocking(fd, False)
        with contextlib.suppress(BlockingIOError):  # a full pipe drops it
            os.write(fd, HEAD.pack(len(data)) + data)


class _PipeReporter:
    """The worker's reporter: progress goes to the parent; Cancel is a kill."""

    def __init__(self, fd: int) -> None:
        self._fd = fd

    def progress(self, fraction: float, message: str = "") -> None:
        _Frames.put(self._fd, "progress", (float(fraction), str(message)[:200]))

    def check_cancelled(self) -> None:
        pass


class _PipeLog(logging.Handler):
    """Sends log records to the parent, which hands them to its own handlers."""

    def __init__(self, fd: int) -> None:
        super().__init__()
        self._fd = fd

    def emit(self, record: logging.LogRecord) -> None:
        try:
            record.msg = record.getMessage()[:1000]
            record.args, record.exc_info, record.exc_text = None, None, None
            _Frames.put(self._fd, "log", record)
        except Exception:  # a record that does not go: never the analysis
            pass


def _log_to(fd: int) -> None:
    """Route every log record to the parent.

    The handlers inherited from it write to files this process closed (or to
    whatever reused their numbers).
    """
    loggers = [logging.getLogger(), *logging.root.manager.loggerDict.values()]
    for logger in loggers:
        if isinstance(logger, logging.Logger):
            for handler in list(logger.handlers):
                logger.removeHandler(handler)
    logging.getLogger().addHandler(_PipeLog(fd))
