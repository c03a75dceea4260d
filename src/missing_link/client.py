"""The host client: open a board by URL, call its functions by name, read its blobs, get its SIFs.

One reader thread per board feeds received bytes and timer ticks into the sans-I/O
:class:`~missing_link.j2a.HostConnection` and resolves ``concurrent.futures.Future`` objects; the
blocking API waits on them, the asyncio API awaits them (``asyncio.wrap_future``).  The connection
state and the writes share one lock, so frames go out in seq order.  Every error path fails the
pending futures and lets the reader thread end: nothing is left holding a lock or running.

SIF handlers run on the reader thread; keep them short (hand work to a queue).
"""

from __future__ import annotations

import asyncio
import logging
import struct
import threading
import time
from collections import deque
from collections.abc import Callable
from concurrent.futures import Future
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, TypeVar

from .descriptors import Transducer, parse_transds
from .errors import (
    BoardError,
    CallError,
    CallTimeout,
    FunctionFailed,
    LinkLost,
    MissingLinkError,
    TransportBroken,
    TransportClosed,
    UnknownFunction,
)
from .j2a import (
    BlobError,
    CallCompleted,
    CallFailed,
    FailureReason,
    FrameDamaged,
    HostConnection,
    SifReceived,
    TransferCompleted,
    TransferProgress,
    parse_mapping,
    parse_properties,
)
from .j2a.blobs import mapping_index
from .timesync import Exchange
from .transport import Transport, open_transport

if TYPE_CHECKING:
    from .reactor import Reactor

log = logging.getLogger(__name__)
T = TypeVar("T")

DEFAULT_TIMEOUT = 1.0
#: the whole handshake (mapping, properties, descriptors) must end within this (s)
HANDSHAKE_TIMEOUT = 5.0
#: caps on what a board may send during the handshake (bytes): a board is untrusted
MAX_MAPPING = 16 << 10
MAX_PROPERTIES = 16 << 10
MAX_TRANSDS = 64 << 10
#: a read_many without a deadline of its own must end within this (s)
TRANSFER_TIMEOUT = 120.0
_TICK = 0.02  # longest the reader sleeps before looking at timers again ...
_IDLE = 1.0  # ... when none is pending and close() wakes the transport's read
SifHandler = Callable[[SifReceived, float], None]
ProgressFn = Callable[[int, "int | None"], None]


@dataclass(frozen=True)
class CallResult:
    code: int
    payload: bytes
    sent_ns: int = 0  #: CLOCK_MONOTONIC ns just before the request was written
    recv_ns: int = 0  #: CLOCK_MONOTONIC ns when the read that completed the reply returned

    @property
    def ok(self) -> bool:
        return self.code == 0


class Board:
    """A connected J2A board (blocking API).  Use :func:`open_board` or ``Board.open(url)``."""

    def __init__(
        self,
        transport: Transport,
        *,
        timeout: float = DEFAULT_TIMEOUT,
        window: int = 1,
        reactor: Reactor | None = None,
    ):
        """``reactor``: read this board in a shared I/O loop (the daemon's, for many boards)
        instead of a reader thread of its own; transports without a descriptor (memory, USB)
        always get their own thread."""
        self.transport = transport
        self.url = transport.url
        self.timeout = timeout
        self.conn = HostConnection(window=window)
        self._lock = threading.Lock()
        # op -> (future, label for errors, progress callback, is a many-write)
        self._futures: dict[int, tuple[Future[Any], str, ProgressFn | None, bool]] = {}
        self._sif_handlers: dict[int, list[SifHandler]] = {}
        self._sent: dict[int, int] = {}  # op -> monotonic ns the request was written
        self._any_sif: list[SifHandler] = []
        self._on_close: list[Callable[[], None]] = []
        self._idle_until = 0.0  # the reader waits until then unless poked
        # Periodic work on the reading thread (clock-sync probes): (due() -> s or None, tick)
        self._ticker: tuple[Callable[[], float | None], Callable[[float], None]] | None = None
        #: CLOCK_MONOTONIC s of the next call deadline or tick, kept up to date under the lock
        #: (a shared I/O loop reads it for its timeout without calling into each board)
        self.next_due: float | None = None
        #: s the reader waits after a read while SIFs stream in, to take several frames per
        #: read (fewer wake-ups and syscalls per update; latency grows by at most this).  A
        #: request written meanwhile ends the wait at once, so replies (and clock sync's t4)
        #: are never read late.  0: read every frame as it comes.
        self.batch_s = 0.0
        self._batch_wake = threading.Event()
        self._stopping = False
        self._closed_reason: BaseException | None = None
        self.functions: list[str] = []
        self.index: dict[str, int] = {}
        self.properties: dict[str, str] = {}
        self.transducers: list[Transducer] | None = None
        self.transds_text: str | None = None
        #: CLOCK_MONOTONIC s when the last intact frame (reply or SIF) arrived: link liveness
        self.last_frame = time.monotonic()
        self._done = threading.Event()  # set when the link has ended and calls were failed
        self._finishing = threading.Lock()
        fileno = getattr(transport, "fileno", None)
        self._reactor = reactor if reactor is not None and fileno is not None else None
        self._thread: threading.Thread | None = None
        if self._reactor is not None:
            self._reactor.add(self)
        else:
            self._thread = threading.Thread(
                target=self._reader, name=f"j2a:{self.url}", daemon=True
            )
            self._thread.start()

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
    ) -> Board:
        """Open ``url`` and read the board's mapping, properties and transducer descriptors."""
        board = cls(open_transport(url), timeout=timeout, window=window)
        try:
            board.handshake(describe=describe, deadline=time.monotonic() + handshake_timeout)
        except BaseException:
            board.close()
            raise
        return board

    @property
    def name(self) -> str:
        return self.properties.get("board.name") or self.url

    @property
    def is_original(self) -> bool:
        """True for a Part 1 (2014 firmware) board: no ``j2a.version`` property."""
        return "j2a.version" not in self.properties

    def handshake(self, *, describe: bool = True, deadline: float | None = None) -> None:
        """Read the mapping, properties and descriptors, all by ``deadline`` (monotonic s;
        default: ``HANDSHAKE_TIMEOUT`` from now), each within its size cap.  What the board
        sends is validated here: errors name the board and the field."""
        if deadline is None:
            deadline = time.monotonic() + HANDSHAKE_TIMEOUT
        total = deadline - time.monotonic()

        def left(what: str) -> float:
            remaining = deadline - time.monotonic()
            if remaining <= 0:
                raise CallTimeout(self.name, what, f"handshake not done within {total:.1f} s")
            return remaining

        # First contact: ask again on a timeout (a board still booting, stale bytes in a pty).
        while True:
            try:
                first = self.call_index(
                    0, b"", "a2jGetMapping", min(self.timeout, left("a2jGetMapping"))
                )
                break
            except CallTimeout:
                left("a2jGetMapping")
        blob = first.payload
        # An original board wraps past 255 bytes; a new one stops at a name boundary and offers
        # the full table through a2jGetMappingMany.
        head = blob[: blob.rfind(b"\0") + 1] if b"\0" in blob else b""
        try:
            names = parse_mapping(head)
            if "a2jGetMappingMany" in names:
                full = self._wait(
                    self._read_future(
                        names.index("a2jGetMappingMany"),
                        "a2jGetMappingMany",
                        max_bytes=MAX_MAPPING,
                        timeout=min(self.timeout, left("a2jGetMappingMany")),
                        deadline=deadline,
                    ),
                    None,
                )
                names = parse_mapping(full)
            self.functions = names
            self.index = mapping_index(names)
        except BlobError as e:
            raise BoardError(self.url, f"bad function mapping: {e}") from e
        if "a2jGetProperties" in self.index:
            raw = self.read_many(
                "a2jGetProperties",
                max_bytes=MAX_PROPERTIES,
                timeout=min(self.timeout, left("a2jGetProperties")),
                deadline=deadline,
            )
            try:
                self.properties = parse_properties(raw)
            except BlobError as e:
                raise BoardError(self.url, f"bad properties: {e}") from e
            _check_properties(self.name, self.properties)
        if describe and "a2jGetTransds" in self.index:
            raw = self.read_many(
                "a2jGetTransds",
                max_bytes=MAX_TRANSDS,
                timeout=min(self.timeout, left("a2jGetTransds")),
                deadline=deadline,
            )
            try:
                self.transds_text = raw.decode("utf-8")
            except UnicodeDecodeError as e:
                raise BoardError(self.name, f"transducer descriptors are not UTF-8: {e}") from e
            self.transducers = parse_transds(self.transds_text, self.name)

    # ---- calls -----------------------------------------------------------------------------
    def _lookup(self, name: str) -> int:
        try:
            return self.index[name]
        except KeyError:
            raise UnknownFunction(self.name, name, self.functions) from None

    def call_future(
        self, name: str, payload: bytes = b"", timeout: float | None = None
    ) -> Future[CallResult]:
        return self._start(
            name, lambda now, t: self.conn.call(self._lookup(name), payload, now, t), timeout
        )

    def call(self, name: str, payload: bytes = b"", timeout: float | None = None) -> CallResult:
        """Call a function by name; returns its return code and reply payload."""
        return self._wait(self.call_future(name, payload, timeout), timeout)

    def clock_exchange(self, timeout: float | None = None, *, byte_ns: float = 0.0) -> Exchange:
        """One ``a2jClock`` round trip: host send/receive stamps and the board's two stamps.

        Boards without ``a2jClock`` but with the thesis firmware's ``getTime`` (u64 µs) give a
        one-stamp exchange (t2 = t3).  ``byte_ns``: time per byte on a UART link, so the reply's
        time on the wire is known (0: not a byte-serial link, or unknown)."""
        name = self._clock_function()
        return self._exchange(name, self._wait(self._clock_call(name, timeout), timeout), byte_ns)

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
                got: Exchange | BaseException = self._exchange(name, fut.result(), byte_ns)
            except MissingLinkError as e:
                got = e
            try:
                callback(got)
            except Exception:
                log.exception("%s: clock exchange callback failed", self.url)

        self._clock_call(name, timeout).add_done_callback(done)

    def _clock_call(self, name: str, timeout: float | None) -> Future[CallResult]:
        """The clock request, with the transport counting arrivals (a tighter t4) from before
        the request is written until its reply, error or timeout resolves it."""
        self.transport.count_arrivals = True
        try:
            fut = self.call_future(name, b"", timeout)
        except BaseException:
            self.transport.count_arrivals = False
            raise
        fut.add_done_callback(self._stop_counting)  # (first: before the caller's callbacks)
        return fut

    def _stop_counting(self, _fut: Future[CallResult]) -> None:
        self.transport.count_arrivals = False

    def _clock_function(self) -> str:
        return "a2jClock" if "a2jClock" in self.index else "getTime"

    def _exchange(self, name: str, result: CallResult, byte_ns: float) -> Exchange:
        p = result.payload
        if result.code != 0 or len(p) not in (8, 16):
            raise FunctionFailed(self.name, name, result.code, p)
        if len(p) == 16:
            t2, t3 = struct.unpack("<QQ", p)
        else:
            (t2,) = struct.unpack("<Q", p)
            t3 = t2
        # On a byte-serial link, the request's bytes before t2 (SOF, seq, op, len, checksum)
        # and the reply's after t3 (SOF, seq, code, len, payload, checksum) are on the wire in
        # every exchange: known delays, not uncertainty.
        return Exchange(
            result.sent_ns, t2, t3, result.recv_ns, int((5 + len(p)) * byte_ns), int(5 * byte_ns)
        )

    def call_ok(self, name: str, payload: bytes = b"", timeout: float | None = None) -> bytes:
        """Call and require return code 0; returns the reply payload."""
        result = self.call(name, payload, timeout)
        if result.code != 0:
            raise FunctionFailed(self.name, name, result.code, result.payload)
        return result.payload

    def call_index(
        self, index: int, payload: bytes, label: str, timeout: float | None = None
    ) -> CallResult:
        fut: Future[CallResult] = self._start(
            label, lambda now, t: self.conn.call(index, payload, now, t), timeout
        )
        return self._wait(fut, timeout)

    def read_many_future(
        self,
        name: str,
        *,
        progress: ProgressFn | None = None,
        max_bytes: int = 64 << 20,
        timeout: float | None = None,
        deadline: float | None = None,
    ) -> Future[bytes]:
        return self._read_future(self._lookup(name), name, progress, max_bytes, timeout, deadline)

    def _read_future(
        self,
        target: int,
        label: str,
        progress: ProgressFn | None = None,
        max_bytes: int = 64 << 20,
        timeout: float | None = None,
        deadline: float | None = None,
    ) -> Future[bytes]:
        return self._start(
            label,
            lambda now, t: self.conn.read_many(
                target,
                now,
                t,
                max_bytes=max_bytes,
                progress=progress is not None,
                deadline=deadline if deadline is not None else now + TRANSFER_TIMEOUT,
                detect_offset_bug=self.is_original,
            ),
            timeout,
            progress,
        )

    def read_many(
        self,
        name: str,
        *,
        progress: ProgressFn | None = None,
        max_bytes: int = 64 << 20,
        timeout: float | None = None,
        deadline: float | None = None,
    ) -> bytes:
        """Read a many-function's whole blob (a2jMany), chunk by chunk.  ``timeout`` is per
        chunk; ``deadline`` (CLOCK_MONOTONIC s) bounds the whole transfer."""
        return self._wait(
            self.read_many_future(
                name, progress=progress, max_bytes=max_bytes, timeout=timeout, deadline=deadline
            ),
            None,
        )

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
        fut: Future[int] = self._start(
            name,
            lambda now, t: self.conn.write_many(
                target, data, now, t, progress=progress is not None
            ),
            timeout,
            progress,
            write=True,
        )
        return self._wait(fut, None)

    def _start(
        self,
        label: str,
        begin: Callable[[float, float], int],
        timeout: float | None,
        progress: ProgressFn | None = None,
        *,
        write: bool = False,
    ) -> Future[Any]:
        fut: Future[Any] = Future()
        with self._lock:
            if self._closed_reason is not None:
                raise self._lost(label, self._closed_reason)
            op = begin(time.monotonic(), timeout or self.timeout)
            self._futures[op] = (fut, label, progress, write)
            sent = time.monotonic_ns()
            try:
                self._flush()
            except (TransportBroken, TransportClosed) as e:
                # The reader thread sees the same failure and fails the rest; this call is ours.
                self._futures.pop(op, None)
                raise self._lost(label, e) from e
            # the transport's stamp is taken right before the write syscall: later, tighter
            self._sent[op] = max(sent, self.transport.last_write_ns)
            timer = self.conn.get_timer()
            idle_until = self._idle_until
            self._update_due()
        if self._on_reading_thread():
            return fut  # (a tick) the reader looks at its timers and futures next anyway
        self._batch_wake.set()  # a reader gathering SIFs reads the reply at once
        if self._reactor is not None:
            self._reactor.poke()  # new timers, and no gathering while a reply is due
        elif timer is not None and timer < idle_until:
            self.transport.poke()  # the reader sleeps past this call's deadline: wake it
        return fut

    def _on_reading_thread(self) -> bool:
        if self._reactor is not None:
            return self._reactor.is_loop_thread()
        return threading.current_thread() is self._thread

    def _wait(self, fut: Future[T], timeout: float | None) -> T:
        if self._reactor is not None and self._reactor.is_loop_thread():
            raise RuntimeError(
                f"{self.url}: a blocking call from the I/O loop (a SIF handler) would wait for a "
                "reply only this thread can read: use call_future() or another thread"
            )
        # The connection always resolves the future (reply, timeout or close); the extra margin
        # only guards against a reader thread that died of a bug.
        limit = (timeout or self.timeout) * 4 + 5.0 if timeout is not None else None
        return fut.result(limit)

    def _flush(self) -> None:
        frames = self.conn.data_to_send()
        if frames:
            self.transport.write_frames(frames)

    def _lost(self, label: str, reason: BaseException) -> LinkLost:
        broken = not isinstance(reason, TransportClosed)
        return LinkLost(self.name, label, str(reason), broken)

    # ---- SIFs ------------------------------------------------------------------------------
    def on_sif(self, cmd: int | None, handler: SifHandler) -> None:
        """Call ``handler(sif, host_receive_time)`` for SIFs with ``cmd`` (None: every SIF)."""
        with self._lock:
            if cmd is None:
                self._any_sif.append(handler)
            else:
                self._sif_handlers.setdefault(cmd, []).append(handler)

    # ---- the reader thread -----------------------------------------------------------------
    def _reader(self) -> None:
        """The board's own reader thread (when no shared I/O loop reads it)."""
        error: BaseException | None = None
        last_data = 0.0
        try:
            while not self._stopping:
                self._tick(time.monotonic())
                with self._lock:  # callers add requests under the lock; never read it bare
                    timer = self.next_due
                    now = time.monotonic()
                    if timer is None:
                        wait = _IDLE if self.transport.wakes_on_close else _TICK
                    else:
                        wait = max(0.0, min(_TICK, timer - now))
                    # set under the lock: a caller that adds a timer after this sees it
                    self._idle_until = now + wait
                data = self.transport.read(wait)
                now = self._step(data, time.monotonic_ns(), self.transport.last_rx_ns)
                if data and self.batch_s > 0:
                    # Streaming (data twice within the window) and no call waiting: gather.
                    if now - last_data < 2 * self.batch_s and not self._futures:
                        self._batch_wake.clear()
                        if not self._futures:
                            self._batch_wake.wait(self.batch_s)
                    last_data = now
        except (TransportBroken, TransportClosed) as e:
            error = e
        except BaseException as e:
            log.exception("%s: reader thread failed", self.url)
            error = TransportBroken(f"{self.url}: reader failed: {e!r}")
        self._finish(error)

    def _step(self, data: bytes, now_ns: int, rx_ns: int) -> float:
        """One turn of reading: the bytes read (maybe none) at ``now_ns`` (monotonic, right
        after the read; ``rx_ns`` is the transport's own stamp if it has one), then whatever
        timers are due.  Returns ``now`` in seconds.  Called by the reader thread or the
        shared I/O loop, never both."""
        now = now_ns / 1e9
        if data and 0 < rx_ns <= now_ns:  # when the bytes arrived (t4): the transport's stamp
            now_ns = rx_ns
        with self._lock:
            timer = self.conn.get_timer()
            if data:
                frames = self.conn.decoder.stats.frames
                events = self.conn.receive_data(data, now)
                if self.conn.decoder.stats.frames != frames:
                    self.last_frame = now
            else:
                events = []
            if timer is not None and now >= timer:
                events += self.conn.handle_timer(now)
            self._flush()
        if events:
            self._dispatch(events, now_ns / 1e9, now_ns)
        with self._lock:
            self._update_due()
        return now

    def _tick(self, now: float) -> None:
        """Run the ticker if it is due.  The reading thread calls this last before it waits
        for bytes, so a request sent here has its reply read (and stamped) at once, not after
        other work: a clock probe's return trip is not lengthened by the host."""
        ticker = self._ticker
        if ticker is None:
            return
        due = ticker[0]()
        if due is None or now < due:
            return
        try:
            ticker[1](now)
        except Exception:  # a bug in the periodic work must not end the reading
            log.exception("%s: tick failed", self.url)
        with self._lock:
            self._update_due()

    def _update_due(self) -> None:
        # (under the lock)
        due = self.conn.get_timer()
        ticker = self._ticker
        if ticker is not None:
            t = ticker[0]()
            if t is not None and (due is None or t < due):
                due = t
        self.next_due = due

    def set_ticker(
        self, due: Callable[[], float | None] | None, tick: Callable[[float], None] | None = None
    ) -> None:
        """Run ``tick(now)`` on the thread that reads this board (its own, or the shared I/O
        loop) whenever ``due()`` (CLOCK_MONOTONIC s, None: nothing due) has passed: periodic
        work that sends requests with ``call_future`` and handles the replies in callbacks,
        without a thread hand-off per request (the clock-sync probes).  ``tick`` must not
        block; ``due`` is called often and must be cheap.  ``set_ticker(None)`` removes it."""
        with self._lock:
            self._ticker = None if due is None or tick is None else (due, tick)
        self.reschedule()

    def reschedule(self) -> None:
        """The ticker's ``due()`` moved (from another thread): look at it again."""
        with self._lock:
            self._update_due()
        if not self._on_reading_thread():
            if self._reactor is not None:
                self._reactor.poke()
            else:
                self.transport.poke()

    def _finish(self, error: BaseException | None) -> None:
        """The link ended: fail what is pending, tell the close callbacks.  Once."""
        with self._finishing:
            if self._done.is_set():
                return
            if error is None:
                error = TransportClosed(f"{self.url}: closed on this side")
            with self._lock:
                self._closed_reason = error
                reason = (
                    FailureReason.CLOSED
                    if isinstance(error, TransportClosed)
                    else FailureReason.BROKEN
                )
                events = self.conn.close(reason, str(error))
            self._dispatch(events, time.monotonic(), time.monotonic_ns())
            self._done.set()
        if self._stopping or isinstance(error, TransportBroken):
            self.transport.close()  # idempotent; the link is over either way
            release = getattr(self.transport, "release", None)
            if release is not None:
                release()  # nothing reads it any more: its wake pipe can go now
        for fn in self._on_close:
            try:
                fn()
            except Exception:
                log.exception("close callback failed")

    def on_close(self, fn: Callable[[], None]) -> None:
        """Call ``fn()`` on the reader thread when the link ends (closed or broken)."""
        self._on_close.append(fn)
        if self._done.is_set():
            fn()

    def _dispatch(self, events: list[Any], now: float, now_ns: int) -> None:
        by_cmd, any_sif = self._sif_handlers, self._any_sif
        for ev in events:
            if type(ev) is SifReceived:  # the sample path: handlers called inline
                by = by_cmd.get(ev.cmd)
                for h in any_sif if by is None else (*by, *any_sif):
                    try:
                        h(ev, now)
                    except Exception:
                        log.exception("SIF handler %r failed", h)
            elif isinstance(ev, TransferProgress):
                entry = self._futures.get(ev.op)
                if entry and entry[2]:
                    try:
                        entry[2](ev.done, ev.total)
                    except Exception:
                        log.exception("progress callback failed")
            elif isinstance(ev, FrameDamaged):
                log.debug("%s: damaged frame: %s", self.url, ev.error)
            else:
                self._resolve(ev, now_ns)

    def _resolve(self, ev: CallCompleted | CallFailed | TransferCompleted, now_ns: int) -> None:
        entry = self._futures.pop(ev.op, None)
        sent = self._sent.pop(ev.op, 0)
        if entry is None:
            return
        fut, label, _, is_write = entry
        if isinstance(ev, CallCompleted):
            fut.set_result(CallResult(ev.code, ev.payload, sent, now_ns))
        elif isinstance(ev, TransferCompleted):
            if is_write:
                fut.set_result(ev.status)  # a write reports the function's status
            elif ev.status == 0:
                fut.set_result(ev.data)
            else:
                fut.set_exception(FunctionFailed(self.name, label, ev.status, ev.data))
        else:
            fut.set_exception(self._failure(label, ev))

    def _failure(self, label: str, ev: CallFailed) -> BoardError:
        if ev.reason is FailureReason.TIMEOUT:
            return CallTimeout(self.name, label, ev.detail)
        if ev.reason in (FailureReason.CLOSED, FailureReason.BROKEN):
            return LinkLost(self.name, label, ev.detail, ev.reason is FailureReason.BROKEN)
        return CallError(self.name, label, ev.detail, ev.code)

    # ---- closing ---------------------------------------------------------------------------
    @property
    def alive(self) -> bool:
        return not self._done.is_set()

    def close(self) -> None:
        """Close the link, fail pending calls, and join the reader thread.  Idempotent."""
        self._stopping = True
        if self._reactor is not None:
            self._reactor.remove(self)  # the loop no longer touches this board when it returns
            self.transport.close()
            self._finish(None)
            return
        self.transport.close()
        if self._thread is not None and threading.current_thread() is not self._thread:
            self._thread.join(timeout=5.0)

    def __enter__(self) -> Board:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def __repr__(self) -> str:
        return f"<Board {self.name} at {self.url}>"


def _check_properties(board: str, props: dict[str, str]) -> None:
    """Range-check the numbers a board states about itself (they steer the host)."""
    res = props.get("clock.res_us")
    if res is not None:
        try:
            value = int(res)
        except ValueError:
            value = 0
        if not 1 <= value <= 1_000_000:
            raise BoardError(
                board, f"property clock.res_us = {res!r}: expected whole µs in 1..1000000"
            )


def open_board(url: str, *, timeout: float = DEFAULT_TIMEOUT, window: int = 1) -> Board:
    """Open a board by URL and read its description (blocking)."""
    return Board.open(url, timeout=timeout, window=window)


class AsyncBoard:
    """The asyncio face of :class:`Board`: the same engine, awaited instead of waited on."""

    def __init__(self, board: Board) -> None:
        self.board = board
        self.dropped = 0  #: SIFs the ``sifs()`` queue had no room for

    @classmethod
    async def open(
        cls, url: str, *, timeout: float = DEFAULT_TIMEOUT, window: int = 1
    ) -> AsyncBoard:
        loop = asyncio.get_running_loop()
        board = await loop.run_in_executor(
            None, lambda: Board.open(url, timeout=timeout, window=window)
        )
        return cls(board)

    @property
    def functions(self) -> list[str]:
        return self.board.functions

    @property
    def properties(self) -> dict[str, str]:
        return self.board.properties

    @property
    def transducers(self) -> list[Transducer] | None:
        return self.board.transducers

    async def call(
        self, name: str, payload: bytes = b"", timeout: float | None = None
    ) -> CallResult:
        return await asyncio.wrap_future(self.board.call_future(name, payload, timeout))

    async def read_many(self, name: str, *, progress: ProgressFn | None = None) -> bytes:
        return await asyncio.wrap_future(self.board.read_many_future(name, progress=progress))

    def sifs(
        self, cmd: int | None = None, maxsize: int = 10000
    ) -> asyncio.Queue[tuple[SifReceived, float]]:
        """A queue that receives ``(sif, host_time)``.  Bounded end to end: when the event loop
        or the consumer falls behind, the newest SIFs are dropped and counted (``dropped``);
        at most one hand-over callback is ever pending in the loop."""
        if maxsize <= 0:
            raise ValueError("maxsize must be > 0: an unbounded queue can eat all memory")
        loop = asyncio.get_running_loop()
        queue: asyncio.Queue[tuple[SifReceived, float]] = asyncio.Queue(maxsize)
        pending: deque[tuple[SifReceived, float]] = deque()
        lock = threading.Lock()
        scheduled = [False]
        self.dropped = 0

        def hand_over() -> None:  # in the loop
            with lock:
                items = list(pending)
                pending.clear()
                scheduled[0] = False
            for item in items:
                try:
                    queue.put_nowait(item)
                except asyncio.QueueFull:
                    self.dropped += 1

        def handler(ev: SifReceived, now: float) -> None:  # on the reader thread
            with lock:
                if len(pending) + queue.qsize() >= maxsize:
                    self.dropped += 1
                    return
                pending.append((ev, now))
                if scheduled[0]:
                    return
                scheduled[0] = True
            try:
                loop.call_soon_threadsafe(hand_over)
            except RuntimeError:  # the loop is closed
                pass

        self.board.on_sif(cmd, handler)
        return queue

    async def close(self) -> None:
        await asyncio.get_running_loop().run_in_executor(None, self.board.close)

    async def __aenter__(self) -> AsyncBoard:
        return self

    async def __aexit__(self, *exc: object) -> None:
        await self.close()


async def open_board_async(url: str, *, timeout: float = DEFAULT_TIMEOUT) -> AsyncBoard:
    return await AsyncBoard.open(url, timeout=timeout)
