"""Calling a J2A function and reading its answer: on a board runtime in this process (no link,
no thread: :func:`call_runtime`), and waiting for a condition (:func:`wait_for`).  A board of any
runtime answers through :meth:`missing_link.testing.RuntimeBoard.call`."""

from __future__ import annotations

import time
from collections.abc import Callable
from typing import Any, NamedTuple

from ..j2a import SOF, Frame, FrameDecoder, FrameKind, encode_frame


class Answer(NamedTuple):
    """A call's answer as the board sent it: its code (0: done, 0xFF: refused, with the
    reason in ``payload``) and its payload.  Compares equal to ``(code, payload)``."""

    code: int
    payload: bytes


def call_runtime(rt: Any, name: str, payload: bytes = b"", seq: int = 7) -> Answer:
    """Call ``name`` on ``rt`` (a ``BoardRuntime``, CPython or the MicroPython one) as a host
    would: the request fed as one frame, its one reply decoded.  What else the runtime had to
    send (SIFs, the log) is taken and dropped with it, as by a host that reads only replies."""
    rt.feed(encode_frame(SOF, seq, rt.index[name], payload))
    replies = rt.take_frames()[0]
    (frame,) = [f for f in FrameDecoder().feed(replies) if isinstance(f, Frame)]
    return Answer(frame.opcode, frame.payload)


def replies(data: bytes, seq: int | None = None) -> list[Frame]:
    """The reply frames (SOF) in ``data``, those with ``seq`` if given; SIFs passed over."""
    frames = [f for f in FrameDecoder().feed(data) if isinstance(f, Frame)]
    return [f for f in frames if f.kind is FrameKind.SOF and seq in (None, f.seq)]


def wait_for(pred: Callable[[], object], timeout: float = 10.0, step: float = 0.02) -> bool:
    """Look at ``pred`` every ``step`` s until it is true or ``timeout`` s passed, and once more
    then.  For tests: the timeout bounds a hang, it is never the threshold a test checks."""
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        if pred():
            return True
        time.sleep(step)
    return bool(pred())
