"""One I/O loop for many boards: the daemon's boards are read by one thread instead of one
reader thread each.

Theory of operation
-------------------
The loop is handed, for each board, two narrow things (as python-can's ``Notifier`` is handed
buses): the descriptor it waits on and reads (a :class:`Readable`: a descriptor transport), and
the link engine it drives (a :class:`Driven`: :class:`~missing_link.host.link.BoardLink`), only
through its public verbs (``step``, ``tick``, ``finish``, ``next_due``, ``calls_waiting``), as
aioquic's loop drives a QUIC connection.  It never looks inside either.  The loop waits in one
``select`` for any board's bytes, the wake pipe, or the soonest timer of any board.  A round then

1. for a board with a clock probe in flight (its transport's ``count_arrivals``), counts the
   bytes waiting the moment the wait returns (``count_arrived``: clock sync's t4, before any
   other work of the round; a reply that heads the read gets the moment the wait returned);
   then reads every ready descriptor (``read_ready``, which returns the bytes and their stamps:
   right after the read, or at that count), so a board's stamp does not wait for another
   board's processing;
2. runs each board's ``step`` with its bytes and their stamps (decode, replies to futures, SIFs
   to the sample path, its due call timers);
3. ends boards whose link broke (``finish``: pending calls fail, close callbacks run);
4. last, right before the next wait, in one pass over the boards (``_due_work``): due call
   timers of boards that had no bytes, then due *tickers* (``BoardLink.set_ticker``: the clock
   probes), so a probe's reply is read the moment it arrives, not after a round's work (which
   would lengthen every return trip alike: a bias no estimator can see); the same pass finds
   the soonest due time, the wait's timeout.

Timers are on the loop's :class:`~missing_link.host.clock.Clock` (the boards it drives share
it); a fake clock's ``advance`` pokes the loop.  The wake-up stamp handed to ``count_arrived``
is a measurement on the transports' timeline (CLOCK_MONOTONIC), whatever the clock.

Why: with a thread per board, every frame cost a wake-up, a select, a lock and an interpreter-lock
hand-off between dozens of threads (the per-update cost grew with the number of boards); one loop
pays a select per round for all boards, and rounds carry several frames.  While samples stream in
and no call waits for a reply, a round is followed by a short gather (``batch_s``) so the next
one carries more; any request written ends it at once (``poke``), so replies and t4 are never
read late.  A gather that brought fewer than two SIFs (a stream slower than the window) only
added a wake-up; the next 100 data rounds then go without one.

Nothing ends the loop but ``stop()``: an exception in a board's ``step`` (a bug: the bytes are a
board's, but the engine checks them) ends that board's link (``finish`` with a broken link) and
is counted in the board's ``faults``; one in the loop's own work is counted in the loop's
``faults`` (the daemon shows them).  Each kind is logged once, with its traceback.

Blocking calls must not be made on this thread (a SIF handler calling ``board.call``): the reply
could only be read by the thread that waits for it; the link raises instead of deadlocking.
Registration is under a lock the loop holds while it processes a round, so when ``remove()``
returns the loop no longer touches that board.
"""

from __future__ import annotations

import logging
import os
import select
import threading
import time
from typing import Protocol

from ..errors import TransportBroken, TransportClosed
from ..logs import ErrorCounts
from ..transport import Received
from .clock import SYSTEM_CLOCK, Clock

log = logging.getLogger(__name__)

_IDLE = 1.0  # longest wait with no timer pending (new timers poke the loop anyway)
_SKIP_GATHERS = 100  # data rounds without gathering after a gather that brought < 2 SIFs


class Readable(Protocol):
    """What the loop waits on and reads: a descriptor transport (FdTransport)."""

    #: a clock reply is awaited: count the bytes waiting the moment the wait returns
    count_arrivals: bool

    def fileno(self) -> int: ...

    def count_arrived(self, woke_ns: int = 0) -> None: ...

    def read_ready(self) -> Received:
        """``(data, rx_ns, first_rx_ns)``: what arrived, and when (never blocks)."""
        ...


class Driven(Protocol):
    """What the loop drives: a board's link engine, through its public verbs only."""

    url: str
    next_due: float | None  #: the loop clock's s of the next call deadline or tick
    faults: ErrorCounts  #: where the loop counts what its ``step`` raised

    @property
    def calls_waiting(self) -> bool: ...

    def step(self, data: bytes, now_ns: int, rx_ns: int = 0, first_rx_ns: int = 0) -> int:
        """The bytes one read brought (maybe none) and their stamps, then due timers; returns
        the SIFs decoded."""
        ...

    def tick(self, now: float) -> None: ...

    def finish(self, error: BaseException | None) -> None: ...


class _Poller:
    """Readable descriptors: epoll where there is one (Linux), else poll.  Plain descriptors in
    and out: the selectors module's keys cost a lookup and an object per ready descriptor per
    round, and its Python work between the kernel's return and the read lengthens t4."""

    def __init__(self) -> None:
        self._epoll = select.epoll() if hasattr(select, "epoll") else None
        self._poll = None if self._epoll is not None else select.poll()

    def register(self, fd: int) -> None:
        if self._epoll is not None:
            self._epoll.register(fd, select.EPOLLIN)
        else:
            assert self._poll is not None
            self._poll.register(fd, select.POLLIN)

    def unregister(self, fd: int) -> None:
        if self._epoll is not None:
            self._epoll.unregister(fd)
        else:
            assert self._poll is not None
            self._poll.unregister(fd)

    def wait(self, timeout: float) -> list[int]:
        # (error and hang-up events count as readable: the read then reports the broken link)
        if self._epoll is not None:
            return [fd for fd, _ in self._epoll.poll(timeout)]
        assert self._poll is not None
        return [fd for fd, _ in self._poll.poll(timeout * 1000.0)]

    def close(self) -> None:
        if self._epoll is not None:
            self._epoll.close()


class Reactor:
    def __init__(self, batch_s: float = 0.0, *, clock: Clock = SYSTEM_CLOCK) -> None:
        self.batch_s = batch_s
        #: what the loop's timers run on; a board read here takes the same one
        self.clock = clock
        self._sel = _Poller()
        self._wake_r, self._wake_w = os.pipe()
        os.set_blocking(self._wake_r, False)
        os.set_blocking(self._wake_w, False)
        self._sel.register(self._wake_r)
        self._lock = threading.RLock()
        self._boards: dict[int, Driven] = {}
        self._ports: dict[int, Readable] = {}
        # registrations counted, and the count at each board's: a descriptor number reused by a
        # board added while the loop waited is not read on the old one's readiness
        self._registrations = 0
        self._registered_at: dict[int, int] = {}
        self._poked = threading.Event()
        self._stopping = False
        self._unwatch = clock.watch(self.poke)  # (a fake clock moved: look at the timers again)
        self._thread = threading.Thread(target=self._run, name="j2a:reactor", daemon=True)
        self.rounds = 0
        #: exceptions in the loop's own work (timers, a round), by kind
        self.faults = ErrorCounts(log, "reactor")

    @property
    def loop_errors(self) -> int:
        """Exceptions in the loop's own work, counted (``faults`` has them by kind)."""
        return self.faults.total

    def start(self) -> Reactor:
        if not self._thread.is_alive():
            self._thread.start()
        return self

    def is_loop_thread(self) -> bool:
        return threading.current_thread() is self._thread

    def add(self, board: Driven, port: Readable) -> None:
        """Read ``port`` and drive ``board`` with what it brings, until ``remove(board)``."""
        with self._lock:
            fd = port.fileno()
            self._sel.register(fd)
            self._boards[fd] = board
            self._ports[fd] = port
            self._registrations += 1
            self._registered_at[fd] = self._registrations
        self.poke()

    def remove(self, board: Driven) -> None:
        with self._lock:
            self._unregister(board)
        self.poke()

    def _unregister(self, board: Driven) -> None:
        # (under the lock)
        for fd, b in list(self._boards.items()):
            if b is board:
                del self._boards[fd]
                del self._ports[fd]
                self._registered_at.pop(fd, None)
                try:
                    self._sel.unregister(fd)
                except (KeyError, ValueError, OSError):  # (closed already: nothing to undo)
                    pass

    def poke(self) -> None:
        self._poked.set()
        try:
            os.write(self._wake_w, b"x")
        except OSError:  # full (already poked) or closed
            pass

    def stop(self, timeout: float = 1.0) -> None:
        self._stopping = True
        self._unwatch()
        self.poke()
        if self._thread.is_alive() and not self.is_loop_thread():
            self._thread.join(timeout)

    def __len__(self) -> int:
        return len(self._boards)

    # ---- the loop ------------------------------------------------------------------------------
    def _run(self) -> None:
        clock = self.clock
        last_data = 0.0
        gathered = False  # the last wait was a gather
        skip = 0  # data rounds to come without a gather
        while not self._stopping:
            try:
                timeout = self._due_work()
            except Exception as e:  # noqa: BLE001 - a bug must not end every board's reading
                self.faults.caught("timers", e, "the loop's timers")
                timeout = _IDLE
            waited_after = self._registrations
            try:
                ready = self._sel.wait(timeout)
                # (a clock reply heading a read was there by now: on the transports' timeline)
                woke = time.monotonic_ns()
            except (OSError, ValueError) as e:  # a descriptor closed under us: next round
                log.debug("reactor: wait: %s", e)
                ready, woke = [], 0
            try:
                ports = self._ports
                for fd in ready:  # first, before any other work: a clock reply's t4
                    port = ports.get(fd)
                    if port is not None and port.count_arrivals:
                        port.count_arrived(woke)
                sifs = self._round(ready, waited_after)
            except Exception as e:  # noqa: BLE001 - (as the timers')
                self.faults.caught("round", e, "a round of reads")
                sifs = 0
            if gathered and sifs < 2:
                # The gather brought one sample or none: the stream is slower than the window
                # (one board at 500/s), so it only added a wake-up; skip it for a while.
                skip = _SKIP_GATHERS
            gathered = False
            now = clock.monotonic()
            if sifs and self.batch_s > 0:
                if skip > 0:
                    skip -= 1
                elif now - last_data < 2 * self.batch_s and not self._calls_waiting():
                    self._poked.clear()
                    if not self._calls_waiting():
                        # (a poke ends it early: a request; that gather is not judged)
                        gathered = not self._poked.wait(self.batch_s)
                last_data = now
        with self._lock:
            self._boards.clear()
            self._ports.clear()
        self._sel.close()
        for fd in (self._wake_r, self._wake_w):
            try:
                os.close(fd)
            except OSError:  # (closed already)
                pass

    def _due_work(self) -> float:
        """Last before the wait, in one pass over the boards: call timeouts that are due, then
        tickers that are due (a probe sent here has its reply read the moment it arrives);
        returns how long the wait may be."""
        clock = self.clock
        now_ns = clock.monotonic_ns()
        now = now_ns / 1e9
        soonest = None
        broken: list[tuple[Driven, BaseException]] = []
        with self._lock:
            for board in list(self._boards.values()):
                due = board.next_due
                if due is not None and now >= due:
                    self._step(board, b"", now_ns, 0, 0, broken)  # call timers (none due: cheap)
                    board.tick(now)
                    due = board.next_due
                if due is not None and (soonest is None or due < soonest):
                    soonest = due
            for board, why in broken:
                self._unregister(board)
                board.finish(why)
        if soonest is None:
            return _IDLE
        return max(0.0, min(_IDLE, soonest - clock.monotonic()))

    def _calls_waiting(self) -> bool:
        return any(b.calls_waiting for b in list(self._boards.values()))

    def _round(self, ready: list[int], waited_after: int) -> int:
        """One round of reads and steps; returns the SIFs it decoded (0: no data).
        ``waited_after``: the registrations counted when the wait began."""
        self.rounds += 1
        with self._lock:
            reads: list[tuple[Driven, Received]] = []
            broken: list[tuple[Driven, BaseException]] = []
            for fd in ready:
                if fd == self._wake_r:
                    try:
                        while os.read(self._wake_r, 4096):
                            pass
                    except (BlockingIOError, OSError):  # (drained: the pokes are read)
                        pass
                    continue
                board = self._boards.get(fd)
                if board is None or self._registered_at[fd] > waited_after:
                    continue  # removed meanwhile, or its number reused by a new board
                try:
                    reads.append((board, self._ports[fd].read_ready()))
                except (TransportBroken, TransportClosed) as exc:
                    broken.append((board, exc))
                except Exception as exc:  # noqa: BLE001 - a transport's bug: its link ends
                    board.faults.caught("read", exc, "reading")  # (its ready fd would spin)
                    broken.append((board, TransportBroken(f"{board.url}: read failed: {exc!r}")))
            now_ns = self.clock.monotonic_ns()
            sifs = 0
            for board, (data, rx_ns, first_rx_ns) in reads:
                # (its due call timers too; bytes without a whole SIF count 1)
                sifs += self._step(board, data, now_ns, rx_ns, first_rx_ns, broken) or 1
            for board, why in broken:
                self._unregister(board)
                board.finish(why)
        return sifs

    @staticmethod
    def _step(
        board: Driven,
        data: bytes,
        now_ns: int,
        rx_ns: int,
        first_rx_ns: int,
        broken: list[tuple[Driven, BaseException]],
    ) -> int:
        try:
            return board.step(data, now_ns, rx_ns, first_rx_ns)
        except (TransportBroken, TransportClosed) as e:  # a write in _flush failed
            broken.append((board, e))
        except Exception as e:  # noqa: BLE001 - a bug in one board's path: its link ends
            board.faults.caught("step", e, "reading")  # (counted where the board's are)
            broken.append((board, TransportBroken(f"{board.url}: reader failed: {e!r}")))
        return 0
