"""Hostile and buggy boards: what the daemon must survive (tests, ``missing-link board --sim``).

Each is a real board runtime with one thing wrong, as a half-flashed, buggy or old board would
have it.  None of them is a mock: they speak J2A over the same links as every virtual board.

``hostile_never_last``   descriptors (a2jGetTransds) that stream for ever without isLast
                         (``slow=True``: one chunk every 50 ms, so only a deadline ends it)
``hostile_offset_bug``   the 2014 firmware's a2jMany bug: only the offset's low byte is used,
                         with a 1000-byte ``bigBlob`` (reads past ~500 bytes never end)
``hostile_res``          clock.res_us = an absurd number
``hostile_table``        a function table padded past 240 entries
``hostile_strings``      \\r, ANSI/OSC escapes and a line separator in its strings
``hostile_glitch``       every ``every``-th SIF of ``signal`` carries a far-future stamp
``hostile_clash``        ``sonar_1`` and ``sonar1`` (both would be message type ``Sonar1``)
``hostile_dtype``        a ``temp`` transducer of data type ``dtype`` (two boards can clash)

Names: ``name`` is board.name as the board states it (``board-a``, ``Bördchen`` and ``""`` are
all fair game for tests).
"""

from __future__ import annotations

import random
import time
from collections.abc import Callable

from ..board.runtime import BoardRuntime, Transducer, read_blob
from .drivers import Counter, rng_for
from .original import OriginalRuntime


def _board(name: str, seed: int, **kw: object) -> BoardRuntime:
    return BoardRuntime(name, "missing-link hostile board", f"hostile-{name}-{seed}", **kw)


def _signal(rt: BoardRuntime, seed: int, rate_hz: float = 200.0) -> Counter:
    counter = Counter(rng_for(seed, "counter"), rate_hz, 1)
    rt.add_transducer(Transducer("signal", 0, "counter", "COUNTER", 1, "int32_t", -1), counter)
    return counter


def never_last(
    seed: int = 0, name: str = "never_last", slow: bool = False, **kw: object
) -> BoardRuntime:
    rt = _board(name, seed, **kw)
    _signal(rt, seed)

    def endless(is_write: bool, is_last: bool, offset: int, data: bytes) -> tuple[int, bool, bytes]:
        if slow:
            time.sleep(0.05)
        return 0, False, b"x" * 249  # data, never the last chunk

    # replace the handler in place: every other function keeps its index
    i = rt.index["a2jGetTransds"]
    rt.functions[i] = ("a2jGetTransds", rt.functions[i][1], endless)
    return rt


def offset_bug(
    seed: int = 0, name: str = "original", periodic: bool = False, size: int = 1000, **kw: object
) -> BoardRuntime:
    """``periodic``: the blob repeats every 256 bytes, so the wrong chunks look right (and
    still no last chunk ever comes)."""
    rt = OriginalRuntime(
        name, "2014 firmware (offset bug)", f"hostile-{name}-{seed}", part2=False, **kw
    )
    rng = random.Random(f"{seed}:blob")
    period = 256 if periodic else size
    blob = (bytes(rng.randrange(256) for _ in range(period)) * (size // period + 1))[:size]
    rt.add_many_function("bigBlob", lambda w, last, off, data: read_blob(blob, off))
    return rt


def res(
    seed: int = 0, name: str = "res", value: str = "99999999999999999999", **kw: object
) -> BoardRuntime:
    rt = _board(name, seed, **kw)
    _signal(rt, seed)
    rt.set_property("clock.res_us", value)
    return rt


def table(seed: int = 0, name: str = "table", size: int = 245, **kw: object) -> BoardRuntime:
    rt = _board(name, seed, **kw)
    # Bypass the runtime's own guard: a hostile board does not check.
    while len(rt.functions) < size:
        fname = f"pad{len(rt.functions)}"
        rt.index[fname] = len(rt.functions)
        rt.functions.append((fname, 0, lambda p: (0, b"")))
    return rt


def strings(seed: int = 0, name: str = "strings", **kw: object) -> BoardRuntime:
    rt = _board(name, seed, **kw)
    rt.add_transducer(
        Transducer(
            "range",
            0,
            "sharp\x1b[31m",
            "GP2Y\rint32 injected",
            1,
            "uint16_t",
            0,
            unit="mm\x1b]0;pwned\x07\u2028",
        ),
        Counter(rng_for(seed, "c"), 100.0, 1),
    )
    rt.set_property("board.model", "evil\x1b[2J\r\nmodel")
    return rt


class _GlitchTransducer(Transducer):  # type: ignore[misc]
    def __init__(self, every: int, *args: object, **kw: object) -> None:
        super().__init__(*args, **kw)
        self.every = every
        self.n = 0
        self.glitches = 0

    def encode_sif(self, now_us: int) -> bytes:
        self.n += 1
        if self.n % self.every == 0:
            # A far-future stamp: what one flipped high bit would do.
            for ch in range(self.chan_count):
                item = self._pending[ch]
                if item is not None:
                    self._pending[ch] = (item[0] | (1 << 52), item[1])
            self.glitches += 1
        out: bytes = super().encode_sif(now_us)
        return out


def glitch(
    seed: int = 0, name: str = "glitch", every: int = 50, rate_hz: float = 200.0, **kw: object
) -> BoardRuntime:
    rt = _board(name, seed, **kw)
    t = _GlitchTransducer(every, "signal", 0, "counter", "COUNTER", 1, "int32_t", -1)
    rt.add_transducer(t, Counter(rng_for(seed, "counter"), rate_hz, 1))
    return rt


def clash(seed: int = 0, name: str = "clash", **kw: object) -> BoardRuntime:
    rt = _board(name, seed, **kw)
    rt.add_transducer(
        Transducer("sonar_1", 0, "srf02", "SRF02", 1, "uint16_t", 0),
        Counter(rng_for(seed, "a"), 50.0, 1),
    )
    rt.add_transducer(
        Transducer("sonar1", 1, "srf02", "SRF02", 1, "uint16_t", 0),
        Counter(rng_for(seed, "b"), 50.0, 1),
    )
    return rt


def dtype(seed: int = 0, name: str = "dtype", dtype: str = "int16_t", **kw: object) -> BoardRuntime:
    rt = _board(name, seed, **kw)
    na = -1.0 if dtype in ("float", "double") else 0
    rt.add_transducer(
        Transducer("temp", 0, "tmp", "TMP36", 1, dtype, na), Counter(rng_for(seed, "t"), 100.0, 1)
    )
    return rt


HOSTILE: dict[str, Callable[..., BoardRuntime]] = {
    "hostile_never_last": never_last,
    "hostile_offset_bug": offset_bug,
    "hostile_res": res,
    "hostile_table": table,
    "hostile_strings": strings,
    "hostile_glitch": glitch,
    "hostile_clash": clash,
    "hostile_dtype": dtype,
}
