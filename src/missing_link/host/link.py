"""The link engine: one board's J2A connection, its pending calls and its SIF handlers, driven
by whoever reads its transport.

Theory of operation
-------------------
The sans-I/O :class:`~missing_link.j2a.HostConnection` turns bytes and timer ticks into events;
this engine turns requests into ``concurrent.futures.Future`` objects and events into results:
replies resolve their futures, SIFs go to their handlers, progress to its callback.  The
connection state and the writes share one lock, so frames go out in seq order.

Something must read the transport and drive the engine.  Either a reader thread of the link's
own (``_reader``: a board opened on its own, or a transport without a descriptor), or a shared
I/O loop (:class:`~missing_link.host.reactor.Reactor`, the daemon's, for many boards), which is
handed the transport to read and this engine to drive.  A driver uses only the public verbs:

* ``step(data, now_ns, rx_ns, first_rx_ns)`` - the bytes one read brought (maybe none) with the
  stamps the read returned, then due timers; returns the SIFs decoded;
* ``tick(now)`` - the periodic work (the clock probes) when ``next_due`` has passed;
* ``finish(error)`` - the link ended: fail what is pending, run the close callbacks (once);
* ``next_due`` and ``calls_waiting`` - when to come back, and whether a reply is awaited.

Time comes from the link's :class:`~missing_link.host.clock.Clock` (call deadlines, tickers,
``last_frame``); the read's stamps (t4) and the transport's write stamp (t1) are used only when
that clock is the system's, whose timeline they are on.

Every error path fails the pending futures and lets the reading end: nothing is left holding a
lock or running.  SIF handlers run on the reading thread; keep them short.  An exception from a
handler, a callback or the ticker (a bug: a board's data is checked before it gets there) does
not end the reading: it is counted by kind in ``faults`` (the session's, when it made the
board: its status shows them) and its first of a kind logged with the traceback.
"""

from __future__ import annotations

import logging
import threading
from collections.abc import Callable
from concurrent.futures import Future
from typing import Any, TypeVar

from ..errors import (
    LinkLost,
    TransportBroken,
    TransportClosed,
)
from ..j2a import (
    CallCompleted,
    CallFailed,
    FailureReason,
    FrameDamaged,
    HostConnection,
    SifReceived,
    TransferCompleted,
    TransferProgress,
)
from ..logs import ErrorCounts
from ..transport import FdTransport, Transport
from .clock import SYSTEM_CLOCK, Clock, never
from .reactor import Reactor
from .results import Asked, CallResult, LinkStats, settle
from .sif_handlers import SifHandler, SifHandlers, named

__all__ = ["DEFAULT_TIMEOUT", "BoardLink", "CallResult", "LinkStats", "ProgressFn", "SifHandler"]

log = logging.getLogger(__name__)
T = TypeVar("T")

DEFAULT_TIMEOUT = 1.0
_TICK = 0.02  # longest the reader sleeps before looking at timers again ...
_IDLE = 1.0  # ... when none is pending and close() wakes the transport's read
ProgressFn = Callable[[int, "int | None"], None]


class BoardLink:
    """One board's link: the engine under :class:`~missing_link.host.board.Board`."""

    def __init__(
        self,
        transport: Transport,
        *,
        timeout: float = DEFAULT_TIMEOUT,
        window: int = 1,
        reactor: Reactor | None = None,
        clock: Clock | None = None,
        name: Callable[[], str] | None = None,
        faults: ErrorCounts | None = None,
    ):
        """``reactor``: read this link in a shared I/O loop (the daemon's, for many boards)
        instead of a reader thread of its own; transports without a descriptor (memory, USB)
        always get their own thread.  ``clock``: what its timers run on (default: the loop's,
        else the system's).  ``name()``: what errors call the board (default: its URL).
        ``faults``: where exceptions caught on its reading thread are counted (default: its
        own; a session hands its own, which outlives the link)."""
        if clock is None:
            clock = reactor.clock if reactor is not None else SYSTEM_CLOCK
        elif reactor is not None and clock is not reactor.clock:
            raise ValueError("a link and the loop that reads it run on one clock")
        self.transport = transport
        self.url = transport.url
        #: exceptions caught on the reading thread (handlers, callbacks, ticker), by kind
        self.faults = faults if faults is not None else ErrorCounts(log, self.url)
        self.timeout = timeout
        self.clock = clock
        self._stamps = clock.real  # the transport's stamps are on this clock's timeline
        self._name = name
        self.conn = HostConnection(window=window)
        self._lock = threading.Lock()
        # op -> (future, label for errors, progress callback, is a many-write)
        self._futures: dict[int, tuple[Future[Any], str, ProgressFn | None, bool]] = {}
        #: who hears which SIFs (sif_handlers.py); what they raise is counted in ``faults``
        self.sifs = SifHandlers(lambda kind, e, what: self.faults.caught(kind, e, what))
        self._sent: dict[int, int] = {}  # op -> monotonic ns the request was written
        self._on_close: list[Callable[[], None]] = []
        self._idle_until = 0.0  # the reader waits until then unless poked
        # Periodic work on the reading thread (clock-sync probes): (due() -> s or None, tick)
        self._ticker: tuple[Callable[[], float | None], Callable[[float], None]] | None = None
        #: the clock's s of the next call deadline or tick, kept up to date under the lock
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
        #: the clock's s when the last intact frame (reply or SIF) arrived: link liveness
        self.last_frame = clock.monotonic()
        self._done = threading.Event()  # set when the link has ended and calls were failed
        self._finishing = threading.Lock()
        on_loop = reactor is not None and isinstance(transport, FdTransport)
        self._reactor = reactor if on_loop else None
        self._thread: threading.Thread | None = None
        # (a fake clock moved: the reader looks at its timers again; a loop watches for itself)
        self._unwatch = clock.watch(transport.poke) if self._reactor is None else never
        if self._reactor is not None:
            assert isinstance(transport, FdTransport)
            self._reactor.add(self, transport)
        else:
            self._thread = threading.Thread(
                target=self._reader, name=f"j2a:{self.url}", daemon=True
            )
            self._thread.start()

    @property
    def name(self) -> str:
        """What errors call this board (its URL unless the owner names it)."""
        return self.url if self._name is None else self._name()

    # ---- requests (for the calls its owner offers) ------------------------------------------
    def request(
        self,
        label: str,
        begin: Callable[[float, float], int],
        timeout: float | None,
        progress: ProgressFn | None = None,
        *,
        write: bool = False,
    ) -> Future[Any]:
        """Start a request: ``begin(now, timeout)`` asks the connection for it (its op);
        the future resolves with its result, or fails with the board's error, a timeout or
        the link's end.  ``label`` names it in errors; ``write``: a many-write (its status)."""
        fut: Future[Any] = Future()
        with self._lock:
            if self._closed_reason is not None:
                raise self._lost(label, self._closed_reason)
            op = begin(self.clock.monotonic(), timeout or self.timeout)
            self._futures[op] = (fut, label, progress, write)
            sent = self.clock.monotonic_ns()
            try:
                self._flush()
            except (TransportBroken, TransportClosed) as e:
                # The reader thread sees the same failure and fails the rest; this call is ours.
                self._futures.pop(op, None)
                raise self._lost(label, e) from e
            # the transport's stamp is taken right before the write syscall: later, tighter
            self._sent[op] = max(sent, self.transport.last_write_ns) if self._stamps else sent
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

    def wait(self, fut: Future[T], timeout: float | None) -> T:
        """Block for a request's result (never on the thread that reads the link)."""
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
            self.sifs.add(cmd, handler)

    # ---- the reader thread -----------------------------------------------------------------
    def _reader(self) -> None:
        """The board's own reader thread (when no shared I/O loop reads it)."""
        error: BaseException | None = None
        clock = self.clock
        last_data = 0.0
        try:
            while not self._stopping:
                self.tick(clock.monotonic())
                with self._lock:  # callers add requests under the lock; never read it bare
                    timer = self.next_due
                    now = clock.monotonic()
                    if timer is None:
                        wait = _IDLE if self.transport.wakes_on_close else _TICK
                    else:
                        wait = max(0.0, min(_TICK, timer - now))
                    # set under the lock: a caller that adds a timer after this sees it
                    self._idle_until = now + wait
                data, rx_ns, first_rx_ns = self.transport.read_stamped(wait)
                now_ns = clock.monotonic_ns()
                self.step(data, now_ns, rx_ns, first_rx_ns)
                if data and self.batch_s > 0:
                    now = now_ns / 1e9
                    # Streaming (data twice within the window) and no call waiting: gather.
                    if now - last_data < 2 * self.batch_s and not self._futures:
                        self._batch_wake.clear()
                        if not self._futures:
                            self._batch_wake.wait(self.batch_s)
                    last_data = now
        except (TransportBroken, TransportClosed) as e:
            error = e
        except BaseException as e:  # noqa: BLE001 - whatever ends the reading, calls fail
            self.faults.caught("reader thread", e, "reading")
            error = TransportBroken(f"{self.url}: reader failed: {e!r}")
        self.finish(error)

    def step(self, data: bytes, now_ns: int, rx_ns: int = 0, first_rx_ns: int = 0) -> int:
        """One turn of reading: the bytes read (maybe none) at ``now_ns`` (the clock's, right
        after the read) with the stamps the read returned (``Transport.read_stamped``: when
        they had all arrived, and when the first had; 0: unknown), then whatever timers are
        due.  Returns the SIFs decoded.  Called by the reader thread or the shared I/O loop,
        never both."""
        now = now_ns / 1e9
        head = 0
        if data and self._stamps:  # when the bytes arrived (t4): the transport's stamps
            if 0 < rx_ns <= now_ns:
                now_ns = rx_ns
            head = first_rx_ns
        with self._lock:
            timer = self.conn.get_timer()
            sifs = self.conn.stats.sifs
            if data:
                frames = self.conn.decoder.stats.frames
                events = self.conn.receive_data(data, now, lead=0 < head < now_ns)
                if self.conn.decoder.stats.frames != frames:
                    self.last_frame = now
            else:
                events = []
            if timer is not None and now >= timer:
                events += self.conn.handle_timer(now)
            self._flush()
            sifs = self.conn.stats.sifs - sifs
        if events:
            self._dispatch(events, now_ns / 1e9, now_ns, head)
        with self._lock:
            self._update_due()
        return sifs

    def tick(self, now: float) -> None:
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
        except Exception as e:  # noqa: BLE001 - a bug in the ticker must not end the reading
            self.faults.caught("tick", e, "the ticker")
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
        loop) whenever ``due()`` (the link clock's s, None: nothing due) has passed: periodic
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

    def finish(self, error: BaseException | None) -> None:
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
            self._dispatch(events, self.clock.monotonic(), self.clock.monotonic_ns())
            self._done.set()
        self._unwatch()
        if self._stopping or isinstance(error, TransportBroken):
            self.transport.close()  # idempotent; the link is over either way
            release = getattr(self.transport, "release", None)
            if release is not None:
                release()  # nothing reads it any more: its wake pipe can go now
        for fn in self._on_close:
            try:
                fn()
            except Exception as e:  # noqa: BLE001 - one bug must not keep the others from running
                self.faults.caught("close callback", e, f"close callback {named(fn)}")

    def on_close(self, fn: Callable[[], None]) -> None:
        """Call ``fn()`` when the link ends (closed or broken), on the thread that ends it:
        the reading thread when the link broke, else the one that closed it or the reader."""
        self._on_close.append(fn)
        if self._done.is_set():
            fn()

    def _dispatch(self, events: list[Any], now: float, now_ns: int, head_ns: int = 0) -> None:
        """``head_ns``: when the first of the read's bytes had arrived (a reply that headed the
        read, ``CallCompleted.lead``, arrived then)."""
        sifs = self.sifs
        by_cmd, every = sifs.by_cmd, sifs.every
        for ev in events:
            if type(ev) is SifReceived:  # the sample path: handlers called inline
                by = by_cmd.get(ev.cmd)
                if by is None and not every:
                    sifs.unheard += 1
                for h in every if by is None else (*by, *every):
                    try:
                        h(ev, now)
                    except Exception as e:  # noqa: BLE001 - a handler's bug must not end the reading
                        sifs.failed(h, e)
            elif isinstance(ev, TransferProgress):
                entry = self._futures.get(ev.op)
                if entry and entry[2]:
                    try:
                        entry[2](ev.done, ev.total)
                    except Exception as e:  # noqa: BLE001 - (as a SIF handler's: the caller's callback)
                        self.faults.caught("progress callback", e, "progress callback")
            elif isinstance(ev, FrameDamaged):
                log.debug("%s: damaged frame: %s", self.url, ev.error)
            else:
                self._resolve(ev, now_ns, head_ns if type(ev) is CallCompleted and ev.lead else 0)

    def _resolve(
        self, ev: CallCompleted | CallFailed | TransferCompleted, now_ns: int, head_ns: int = 0
    ) -> None:
        entry = self._futures.pop(ev.op, None)
        sent = self._sent.pop(ev.op, 0)
        if entry is not None:
            fut, label, _, is_write = entry
            settle(fut, ev, Asked(self.name, label, is_write, sent), now_ns, head_ns)

    @property
    def alive(self) -> bool:
        return not self._done.is_set()

    def stats(self) -> LinkStats:
        """The link's counters now (a snapshot: the reading goes on meanwhile)."""
        with self._lock:
            counts = self.conn.stats.as_dict()
        return LinkStats(
            **counts, unheard_sifs=self.sifs.unheard, transport=self.transport.link_stats()
        )

    def expect_sif_seq(self, seq: int) -> None:
        """The seq of the next SIF (the board's boot is the one before an outage): a gap from
        it counts as SIFs lost."""
        with self._lock:
            self.conn.expect_sif_seq(seq)

    def count_lost_sifs(self, n: int) -> None:
        """SIFs lost that the seq cannot show (its whole wraps, from the board's own count)."""
        with self._lock:
            self.conn.stats.lost_sifs += n

    @property
    def calls_waiting(self) -> bool:
        """A request awaits its reply (a shared loop does not gather SIFs meanwhile)."""
        return bool(self._futures)

    def close(self) -> None:
        """Close the link, fail pending calls, and join the reader thread.  Idempotent."""
        self._stopping = True
        if self._reactor is not None:
            self._reactor.remove(self)  # the loop no longer touches this board when it returns
            self.transport.close()
            self.finish(None)
            return
        self.transport.close()
        if self._thread is not None and threading.current_thread() is not self._thread:
            self._thread.join(timeout=5.0)
