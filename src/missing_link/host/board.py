"""The host's view of one board: open it by URL, call its functions by name, read its blobs,
exchange clock stamps, get its SIFs (blocking API; :mod:`.aio` awaits the same engine).

``Board.open(url)`` reads the board's description in one handshake with one deadline and caps on
every size (a board is untrusted): the function mapping (opcode 0, or ``a2jGetMappingMany`` when
it does not fit a frame), the properties and the transducer descriptors.  A board holds its link
engine (:mod:`.link`, ``board.link``) and goes through it for every call: blocking calls wait on
its futures, and ``call_future`` / ``clock_exchange_async`` hand the reply to a callback
instead.  Whatever reads the link (its own thread, or a shared I/O loop) drives the engine, not
the board.  Deadlines are on the board's clock (:mod:`.clock`; the system's unless given).
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from concurrent.futures import Future
from typing import TYPE_CHECKING, Any, TypedDict, Unpack

from ..closing import Closing
from ..delegate import Delegate
from ..errors import (
    CallError,
    FunctionFailed,
    MissingLinkError,
    UnknownFunction,
)
from ..logs import ErrorCounts
from ..timesync.exchange import Exchange
from ..transport import Transport, open_transport
from .board_log import LogLines
from .clock import Clock
from .handshake import HANDSHAKE_TIMEOUT, handshake
from .link import DEFAULT_TIMEOUT, BoardLink, ProgressFn, SifHandler
from .reactor import Reactor
from .results import CallResult, LinkStats, exchange_of

if TYPE_CHECKING:  # (loaded where used: a one-off call reads no descriptors, sets no keys)
    from ..descriptors import Transducer
    from .config import BoardConfig, Value

#: a read_many without a deadline of its own must end within this (s)
TRANSFER_TIMEOUT = 120.0

__all__ = ["HANDSHAKE_TIMEOUT", "Board", "CallResult", "LinkStats", "open_board"]


class LinkOptions(TypedDict, total=False):
    """A board's link engine's keywords (:class:`~.link.BoardLink`: their defaults, meanings)."""

    timeout: float
    window: int
    reactor: Reactor | None
    clock: Clock | None
    faults: ErrorCounts | None


class ManyRead(TypedDict, total=False):
    """An a2jMany read's keywords (``Board.read_many_future``: their defaults)."""

    progress: ProgressFn | None
    max_bytes: int
    timeout: float | None
    deadline: float | None


class Board(LogLines, Closing):
    """A connected J2A board (blocking API; its log: ``on_log``).  Use ``Board.open(url)``."""

    def __init__(self, transport: Transport, **link: Unpack[LinkOptions]):
        """``link``: how its link engine runs (:class:`~.link.BoardLink`'s keywords: the call
        timeout, the window, a shared ``reactor`` to be read in, the ``clock`` deadlines run
        on, where ``faults`` on its reading thread are counted)."""
        self.functions: list[str] = []
        self.index: dict[str, int] = {}
        self.properties: dict[str, str] = {}
        self.transducers: list[Transducer] | None = None
        self.transds_text: str | None = None
        self._settings: BoardConfig | None = None
        self._link = BoardLink(transport, name=lambda: self.name, **link)

    # ---- the link (board.link: the engine, with its connection, transport and tickers) -------
    @property
    def link(self) -> BoardLink:
        """The link engine this board holds (what a loop drives; benchmarks step it)."""
        return self._link

    url = Delegate[str]("_link")
    #: a call's timeout when it gives none (s)
    timeout = Delegate[float]("_link")
    #: what the board's deadlines, timers and ``last_frame`` run on
    clock = Delegate[Clock]("_link")
    alive = Delegate[bool]("_link")
    #: when the last intact frame (reply or SIF) arrived, on the board's clock (s)
    last_frame = Delegate[float]("_link")

    def link_stats(self) -> LinkStats:
        """The link's counters now: frames, damage, calls, SIFs lost, the transport's own."""
        return self._link.stats()

    def on_sif(self, cmd: int | None, handler: SifHandler) -> None:
        """Call ``handler(sif, host_receive_time)`` for SIFs with ``cmd`` (None: every SIF),
        on the thread that reads the board."""
        self._link.on_sif(cmd, handler)

    def on_close(self, fn: Callable[[], None]) -> None:
        """Call ``fn()`` when the link ends (closed or broken): ``BoardLink.on_close``."""
        self._link.on_close(fn)

    def close(self) -> None:
        """Close the link, fail pending calls, end its reading.  Idempotent."""
        self._link.close()

    # ---- opening ---------------------------------------------------------------------------
    @classmethod
    def open(
        cls,
        url: str,
        *,
        timeout: float = DEFAULT_TIMEOUT,
        window: int = 1,
        describe: bool = True,
        handshake_timeout: float = HANDSHAKE_TIMEOUT,
        clock: Clock | None = None,
    ) -> Board:
        """Open ``url`` and read the board's mapping, properties and transducer descriptors."""
        board = cls(open_transport(url), timeout=timeout, window=window, clock=clock)
        try:
            board.handshake(describe=describe, deadline=board.clock.monotonic() + handshake_timeout)
        except BaseException:  # (broad, and raised again: Ctrl-C too must not leak the link)
            board.close()
            raise
        return board

    @property
    def name(self) -> str:
        return self.properties.get("board.name") or self.url

    @property
    def is_original(self) -> bool:
        """True for a Part 1 (2014 firmware) board: no ``j2a.version`` property (and no
        ``a2jGetMappingMany``, which tells a Part 2 board before its properties are read)."""
        return "j2a.version" not in self.properties and "a2jGetMappingMany" not in self.index

    def handshake(self, *, describe: bool = True, deadline: float | None = None) -> None:
        """Read the mapping, properties and descriptors, all by ``deadline`` (the board
        clock's s; default: ``HANDSHAKE_TIMEOUT`` from now), each within its size cap
        (handshake.py).  What the board sends is validated: errors name the board and the
        field."""
        handshake(self, describe=describe, deadline=deadline)

    # ---- calls -----------------------------------------------------------------------------
    def _lookup(self, name: str) -> int:
        try:
            return self.index[name]
        except KeyError:
            raise UnknownFunction(self.name, name, self.functions) from None

    def call_future(
        self, name: str, payload: bytes = b"", timeout: float | None = None
    ) -> Future[CallResult]:
        return self._link.request(
            name, lambda now, t: self._link.conn.call(self._lookup(name), payload, now, t), timeout
        )

    def call(self, name: str, payload: bytes = b"", timeout: float | None = None) -> CallResult:
        """Call a function by name; returns its return code and reply payload."""
        return self._link.wait(self.call_future(name, payload, timeout), timeout)

    def clock_exchange(self, timeout: float | None = None, *, byte_ns: float = 0.0) -> Exchange:
        """One ``a2jClock`` round trip: host send/receive stamps and the board's two stamps.

        Boards without ``a2jClock`` but with the thesis firmware's ``getTime`` (u64 µs) give a
        one-stamp exchange (t2 = t3).  ``byte_ns``: time per byte on a UART link, so the reply's
        time on the wire is known (0: not a byte-serial link, or unknown)."""
        name = self._clock_function()
        result = self._link.wait(self._clock_call(name, timeout), timeout)
        return exchange_of(self.name, name, result, byte_ns)

    def clock_exchange_async(
        self,
        callback: Callable[[Exchange | BaseException], None],
        timeout: float | None = None,
        *,
        byte_ns: float = 0.0,
    ) -> None:
        """Start a :meth:`clock_exchange`; ``callback`` gets the exchange or the error
        (``MissingLinkError``) on the thread that reads the board.  Raises ``LinkLost`` at
        once when the link is gone."""
        name = self._clock_function()

        def done(fut: Future[CallResult]) -> None:
            try:
                got: Exchange | BaseException = exchange_of(self.name, name, fut.result(), byte_ns)
            except MissingLinkError as e:
                got = e
            try:
                callback(got)
            except Exception as e:  # noqa: BLE001 - a callback's bug must not end the reading
                self._link.faults.caught("clock exchange callback", e)

        self._clock_call(name, timeout).add_done_callback(done)

    def _clock_call(self, name: str, timeout: float | None) -> Future[CallResult]:
        """The clock request, with the transport counting arrivals (a tighter t4) from before
        the request is written until its reply, error or timeout resolves it."""
        self._link.transport.count_arrivals = True
        try:
            fut = self.call_future(name, b"", timeout)
        except BaseException:  # (broad, and raised again: whatever failed, stop counting)
            self._link.transport.count_arrivals = False
            raise
        fut.add_done_callback(self._stop_counting)  # (first: before the caller's callbacks)
        return fut

    def _stop_counting(self, _fut: Future[CallResult]) -> None:
        self._link.transport.count_arrivals = False

    def _clock_function(self) -> str:
        return "a2jClock" if "a2jClock" in self.index else "getTime"

    def call_ok(self, name: str, payload: bytes = b"", timeout: float | None = None) -> bytes:
        """Call and require return code 0; returns the reply payload."""
        result = self.call(name, payload, timeout)
        if result.code != 0:
            raise FunctionFailed(self.name, name, result.code, result.payload)
        return result.payload

    def call_index(
        self, index: int, payload: bytes, label: str, timeout: float | None = None
    ) -> CallResult:
        fut: Future[CallResult] = self._link.request(
            label, lambda now, t: self._link.conn.call(index, payload, now, t), timeout
        )
        return self._link.wait(fut, timeout)

    def read_many_future(
        self,
        name: str,
        *,
        progress: ProgressFn | None = None,
        max_bytes: int = 64 << 20,
        timeout: float | None = None,
        deadline: float | None = None,
    ) -> Future[bytes]:
        target = self._lookup(name)
        return self._link.request(
            name,
            lambda now, t: self._link.conn.read_many(
                target,
                now,
                t,
                max_bytes=max_bytes,
                progress=progress is not None,
                deadline=deadline if deadline is not None else now + TRANSFER_TIMEOUT,
                original=self.is_original,
            ),
            timeout,
            progress,
        )

    def read_many(self, name: str, **many: Unpack[ManyRead]) -> bytes:
        """Read a many-function's whole blob (a2jMany), chunk by chunk: ``read_many_future``,
        waited for.  ``timeout`` is per chunk; ``deadline`` (CLOCK_MONOTONIC s) bounds the
        whole transfer."""
        return self._link.wait(self.read_many_future(name, **many), None)

    def write_many(
        self,
        name: str,
        data: bytes,
        *,
        progress: ProgressFn | None = None,
        timeout: float | None = None,
    ) -> int:
        """Write ``data`` to a many-function; returns the function's status (0 = OK)."""
        target = self._lookup(name)
        try:
            fut: Future[int] = self._link.request(
                name,
                lambda now, t: self._link.conn.write_many(
                    target, data, now, t, progress=progress is not None, original=self.is_original
                ),
                timeout,
                progress,
                write=True,
            )
        except ValueError as e:  # a blob the board cannot take (the connection says why)
            raise CallError(self.name, name, str(e)) from None
        return self._link.wait(fut, None)

    def describe(self) -> dict[str, Any]:
        """What ``missing-link info --json`` shows: functions, properties, transducers."""
        return {
            "name": self.name,
            "url": self.url,
            "original": self.is_original,
            "functions": [{"index": i, "name": n} for i, n in enumerate(self.functions)],
            "properties": dict(self.properties),
            "transducers": None
            if self.transducers is None
            else [t.to_json() for t in self.transducers],
            "configurable": self.settings.available,
        }

    # ---- run-time configuration (host/config.py) ---------------------------------------------
    @property
    def settings(self) -> BoardConfig:
        """The board's run-time configuration functions (keys, limits, state)."""
        if self._settings is None:
            from .config import BoardConfig

            self._settings = BoardConfig(self)
        return self._settings

    def config(self) -> dict[str, Value]:
        """Every ``<transducer>.<key>`` and its value now (NotConfigurable for a board without
        run-time configuration, e.g. the 2014 firmware)."""
        return self.settings.read()

    def configure(self, values: Mapping[str, object], save: bool = False) -> dict[str, Value]:
        """Set several keys at once, all or none; ``save`` keeps them on the board across
        resets.  ConfigError (nothing sent) for an unknown key or a value it does not allow;
        ConfigRefused when the board refuses.  Returns the configuration after it."""
        return self.settings.configure(values, save)

    def reset_config(self, erase_saved: bool = False) -> dict[str, Value]:
        """The board file's defaults again (``erase_saved``: forget the saved ones too)."""
        return self.settings.reset(erase_saved)

    def __repr__(self) -> str:
        return f"<Board {self.name} at {self.url}>"


def open_board(
    url: str, *, timeout: float = DEFAULT_TIMEOUT, window: int = 1, clock: Clock | None = None
) -> Board:
    """Open a board by URL and read its description (blocking)."""
    return Board.open(url, timeout=timeout, window=window, clock=clock)
