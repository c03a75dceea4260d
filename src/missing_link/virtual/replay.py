"""A recorded board, played back as a board (``missing-link replay``): the board runtime of the
virtual boards, fed from a recording instead of drivers.

Theory of operation
-------------------
:class:`ReplayRuntime` is a :class:`~missing_link.board.runtime.BoardRuntime` whose function
table, properties, descriptors (served as recorded, byte for byte) and run-time configuration
are the recorded board's, and whose clock is the recorded clock (replay_clock.py): the host's
clock sync meets the recorded offset, skew and resets.  It speaks J2A like any virtual board
(``BoardServer``: a pty, TCP, memory).

Samples: a feeder thread reads the board's recorded SIFs (recording.py) ahead into a bounded
queue; ``poll`` sends each once it is due, in recorded order: when the recording's host time
(on the timeline) has reached both its recorded host time and the moment the board clock reads
its newest stamp, so no sample comes before its own measurement.  Each goes out with its
recorded board stamps and values and its recorded SIF seq (so what the recording lost is lost
again).  Until the board's host is ready, while no host is connected to a socket, and while
more than ``BACKLOG`` bytes wait for the host to read them (a host that falls behind, e.g. at
``--rate 10``), due samples wait rather than be lost; one sent over ``LATE_NS`` after it was
due counts as ``late``.  A host is ready once it has synced (eight clock exchanges answered:
``a2jClock``, or ``getTime`` for a 2014 board; or ``READY_S`` after its first request: a host
that does not sync) and has read the board's count of SIFs (``a2jSifCount``: a daemon listens
for SIFs from before it asks, so none falls between its count and its listening, however slow
the machine; a host that never asks, ``READY_S`` after its first request; a board without the
function, ``lead_s`` after it); again for each new host: a new connection, or a handshake
(``a2jGetMapping``) on a pty, whose hosts come and go unseen (a daemon that lost a reply in its
handshake comes back after its call timeout, with samples due, and takes none until it listens
again).  What one turn sends
counts in the backlog at once, so a host that comes back to many due samples gets them paced
by what it reads, not shed by the link's queue.

The configuration starts as recorded when the recording began and follows the changes the
recording's host made, at their recorded times.  What this host does is taken as a board takes
it: configuration sets are checked against the recorded key table and applied, all or none, to
what it reports (``<transducer>.enabled =
false`` withholds that transducer's samples: ``withheld``); actuator calls (``call=`` of an
actuator) are checked against the data type and counted (``commands``), and change nothing
recorded; ``a2jAt``, ``a2jHostMap``, ``a2jGoodbye`` work as on any board.  A function the
recording names but cannot say what it did answers 0xFF and says so.  A new boot of the
recorded clock (a reset it saw, or a new pass of ``--loop``) is a new ``clock.epoch``, as a
board that restarted.
"""

from __future__ import annotations

import functools
import queue
import struct
import threading
import time
from collections.abc import Callable
from typing import Any

from ..board.failsafe import Failsafe
from ..board.runtime import BoardRuntime
from ..board.timing import Timing
from ..descriptors import Transducer
from ..j2a.codec import SOS, encode_frame
from .recording import PairStats, RecordedBoard, RecordedSif, Recording, recorded_sifs
from .replay_clock import Clock
from .replay_config import Channel, ReplayConfig, config_keys

READY_EXCHANGES = 8  #: clock exchanges answered before the host counts as synced
#: ... or this long after its first request: a host that does not sync, or does not read the
#: board's count of SIFs (a daemon listens from then: ``_ready_ns``).  Longer than a daemon's
#: handshake may take on one connection (``handshake_timeout``, 5 s; then it reconnects) and its
#: first sync's call (``timeout``, 1 s): a daemon whose handshake lost a reply (it waits its 1 s
#: call timeout) is not taken for one and sent samples it drops
READY_S = 6.0
#: recorded SIFs read ahead, all boards together (what a replay holds of them), each board at
#: least MIN_AHEAD (a second of a 1 kHz board)
AHEAD = 20_000
MIN_AHEAD = 1_000
LATE_NS = 50_000_000  #: a SIF sent this long after it was due counts as late
BACKLOG = 16 * 1024  #: output bytes waiting for the host above which samples wait too
NOBODY = 1 << 62  #: the backlog when no host is connected
_PLAIN = 0  # a plain function (board/runtime.py's kind)


class Feeder:
    """Reads one board's recorded SIFs ahead, pass after pass; ``None`` ends a pass."""

    def __init__(self, rec: Recording, board: str, loop: bool, boards: int = 1) -> None:
        """``boards``: how many read ahead beside it (their share of AHEAD each)."""
        self.stats = PairStats()
        self.queue: queue.Queue[RecordedSif | None] = queue.Queue(max(MIN_AHEAD, AHEAD // boards))
        self._stop = threading.Event()
        self._args = (rec, board, loop)
        self.error = ""
        self.thread = threading.Thread(target=self._run, name=f"replay-feed:{board}", daemon=True)

    def _put(self, item: RecordedSif | None) -> bool:
        while not self._stop.is_set():
            try:
                self.queue.put(item, timeout=0.2)
                return True
            except queue.Full:
                continue
        return False

    def _run(self) -> None:
        rec, board, loop = self._args
        try:
            while True:
                for sif in recorded_sifs(rec, board, self.stats):
                    if not self._put(sif):
                        return
                if not self._put(None) or not loop:
                    return
        except Exception as e:  # noqa: BLE001 - a file that broke under us ends the feed, loudly
            self.error = f"{board}: reading the recording failed: {type(e).__name__}: {e}"
            self._put(None)

    def stop(self) -> None:
        self._stop.set()


class ReplayRuntime(BoardRuntime):  # type: ignore[misc]
    """One recorded board, served again (see the module's theory of operation)."""

    functions: list[tuple[str, int, Any]]  # (BoardRuntime's, untyped)
    index: dict[str, int]

    def __init__(self, board: RecordedBoard, clock: Clock, feeder: Feeder) -> None:
        self.replay_clock = clock
        self.timeline = clock.timeline
        self.feeder = feeder
        self.recorded = board
        self._boot = (0, clock.model.boot_at(float(clock.timeline.first)))
        props = dict(board.description.properties)
        super().__init__(props.get("board.name", board.name), props.get("board.model", ""),
                         props.get("board.serial", ""), clock=self._now_us,
                         epoch=clock.epoch(*self._boot))  # fmt: skip
        self.properties = props
        self._epoch()
        self.channels = {t.name: Channel(t.name) for t in board.transducers.values()}
        self.commands: dict[str, int] = {}
        self.sent = self.withheld = 0
        self.late = 0  #: SIFs sent more than LATE_NS after they were due (a host not ready)
        self.bad = 0  #: recorded samples and changes that could not be played (skipped)
        self.said = ""  #: the first of them, said by the replay (replay_serve.py)
        self.exchanges = 0  # a2jClock requests answered
        self.first_request: int | None = None  # monotonic ns
        self.hosts = 0  #: host connections so far (the server counts them)
        self._host_since: int | None = None  # the current host's first request
        self._host_exchanges = 0
        self._host_synced: int | None = None  # when it had READY_EXCHANGES answered
        self._host_counted: int | None = None  # when it asked a2jSifCount (it listens by then)
        self.backlog = 0  #: output bytes the host has not taken yet (the server says)
        self.finished = False  # the last pass is out
        self.passes = 0
        self._next: RecordedSif | None = None
        self._due_h = float("-inf")  # the recording's host time the next SIF is due at
        self._last_rec_seq: int | None = None
        self._gap = 0
        self._sif_boot = -1
        self._build(board)

    # ---- the board's description --------------------------------------------------------------
    def _build(self, board: RecordedBoard) -> None:
        functions = board.description.functions
        transds = board.description.transds.encode()
        if "a2jGetTransds" in self.index:
            i = self.index["a2jGetTransds"]
            self.functions[i] = ("a2jGetTransds", 1, self._blob(lambda: transds))
        for t in board.transducers.values():
            if t.is_actuator and t.call and t.call not in self.index:
                self.add_function(t.call, self._actuator(t))
        if "getTime" in functions:  # the thesis's: the board clock now
            self.add_function("getTime", lambda p: (0, struct.pack("<Q", self.clock())))
        if "a2jAt" in functions:
            self.timing = Timing(self)
            self.timing.calls = {t.call for t in board.transducers.values() if t.is_actuator}
        if "a2jGoodbye" in functions:
            self.failsafe = Failsafe(self)
        if "a2jConfigKeys" in functions and board.config is not None:
            self.config = ReplayConfig(self, config_keys(board, self.channels))
        self._changes = 1  # the next recorded configuration change (board.configs)
        have = {entry[0]: entry for entry in self.functions}
        table = [have.get(name, (name, _PLAIN, _not_reproduced(name))) for name in functions]
        self.functions = table
        self.index = {name: i for i, (name, _k, _h) in enumerate(table)}
        self._clock_op = self.index.get("a2jClock", -1)
        #: the requests a host syncs with (getTime: how it syncs a 2014 board)
        self._sync_ops = {self.index[n] for n in ("a2jClock", "getTime") if n in self.index}
        self._mapping_op = self.index.get("a2jGetMapping", -1)  # (a host's first request)
        self._count_op = self.index.get("a2jSifCount", -1)

    def _blob(self, make: Callable[[], bytes]) -> Callable[[bool, bool, int, bytes], Any]:
        from ..board.runtime import read_blob

        def handler(is_write: bool, is_last: bool, offset: int, data: bytes) -> Any:
            return (0xFF, False, b"") if is_write else read_blob(make(), offset)

        return handler

    def _actuator(self, t: Transducer) -> Callable[[bytes], tuple[int, bytes]]:
        vs = t.value_struct()

        def call(payload: bytes) -> tuple[int, bytes]:
            if not self.channels[t.name].enabled:
                return 0xFF, f"{t.name} is disabled".encode()
            if len(payload) != vs.size:
                return 0xFF, f"expects one {t.dtype}".encode()
            (value,) = vs.unpack(payload)
            if not t.legal(value):
                return 0xFF, f"{value} is not a {t.dtype} command".encode()
            self.commands[t.name] = self.commands.get(t.name, 0) + 1
            return 0, b""

        return call

    # ---- the clock and the host -----------------------------------------------------------------
    def _now_us(self) -> int:
        k, boot, b = self.replay_clock.read(time.monotonic_ns())
        if (k, boot) != self._boot:
            self._boot = (k, boot)  # a new boot: what a board that restarted has
            self._epoch()
            self.host_map = None
        return b

    def _epoch(self) -> None:
        if "clock.epoch" in self.properties:  # (a 2014 board has none)
            self.properties["clock.epoch"] = self.replay_clock.epoch(*self._boot)

    def new_host(self, hosts: int) -> None:
        """Another host connected: it is ready once it has synced, as the first."""
        self.hosts = hosts
        self._host_since, self._host_exchanges, self._host_synced = None, 0, None
        self._host_counted = None

    def feed(self, data: bytes, rx_us: int | None = None) -> None:
        if data and self._host_since is None:
            now = time.monotonic_ns()
            self._host_since = now
            if self.first_request is None:
                self.first_request = now
                self.timeline.start(now)
                rx_us = self.clock()  # (read again: the timeline has just started)
        super().feed(data, rx_us)

    def _dispatch(self, seq: int, opcode: int, payload: bytes) -> None:
        if opcode in self._sync_ops:
            self.exchanges += 1
            self._host_exchanges += 1
            if self._host_exchanges == READY_EXCHANGES:
                self._host_synced = time.monotonic_ns()
        elif opcode == self._count_op:
            self._host_counted = time.monotonic_ns()
        elif opcode == self._mapping_op and (self._host_exchanges or self._host_counted):
            self.new_host(self.hosts)  # a handshake again: a new host (a pty does not say)
            self._host_since = time.monotonic_ns()
        super()._dispatch(seq, opcode, payload)

    def _ready_ns(self) -> int | None:
        """When the current host is ready for samples (monotonic ns; None: not yet known):
        once it has synced and listens: from its a2jSifCount request (a daemon), or
        ``READY_S`` after its first request for a host that never asks; a board without the
        function (a 2014 board), ``lead_s`` after it, as the recording's start is after the
        first host's.  A host that came back after the recording began (a reply lost in its
        handshake: its call timeout, a new connection) would otherwise get every sample due
        meanwhile before it listens."""
        since = self._host_since
        if since is None:
            return None
        late = since + round(READY_S * 1e9)  # (a host that does not sync, or never counts)
        synced = late if self._host_synced is None else min(late, self._host_synced)
        if self._host_counted is not None:
            return max(synced, self._host_counted)
        if self._count_op >= 0:  # (it may yet ask: a daemon listens once it does)
            return late
        return max(synced, since + self.timeline.lead_ns)

    def _ready(self, now: int) -> bool:
        at = self._ready_ns()
        return at is not None and now >= at

    # ---- samples --------------------------------------------------------------------------------
    def poll(self) -> None:
        super().poll()
        if not self.timeline.started:
            return
        now = time.monotonic_ns()
        configs = self.recorded.configs
        while self.config is not None and self._changes < len(configs):
            at, record = configs[self._changes]
            if self.timeline.mono_at(self.passes, at) > now:
                break
            self._changes += 1
            self._safely(functools.partial(self.config.follow, record), "a configuration change")
        while True:
            sif = self._peek()
            if sif is None:
                return
            due = self.timeline.mono_at(self.passes, self._due_h)
            if due > now or not self._ready(now) or self.backlog > BACKLOG:
                return
            if now - due > LATE_NS:
                self.late += 1
            self._next = None
            self._safely(functools.partial(self._send, sif), "a sample")

    def _safely(self, step: Callable[[], None], what: str) -> None:
        """One step of the recording played; one that fails is counted and skipped (the file
        is anyone's: a record recording.py let through that still cannot be played must not
        end the board's thread), the first said."""
        try:
            step()
        except Exception as e:  # noqa: BLE001 - (see above: counted, said once, skipped)
            self.bad += 1
            if self.bad == 1:
                self.said = f"{what} of the recording cannot be played ({type(e).__name__}: {e})"

    def _peek(self) -> RecordedSif | None:
        """The next recorded SIF (its due time in ``_due_h``), None while none is there."""
        while self._next is None:
            try:
                sif = self.feeder.queue.get_nowait()
            except queue.Empty:
                return None
            if sif is None:  # the end of a pass
                self.finished = not self.timeline.loop
                if self.finished:
                    return None
                self.passes += 1
                self._due_h = float("-inf")
                self._last_rec_seq = None  # (the next pass is a new boot)
                if self.config is not None and self.recorded.config is not None:
                    self.config.follow(self.recorded.config)  # (as it was at the start)
                    self._changes = 1
                continue
            model = self.replay_clock.model
            boot = model.boots[model.boot_at(sif.log_ns)]
            due = min(max(float(sif.log_ns), boot.host_at(max(sif.board_us))), sif.log_ns + 1e9)
            self._due_h = max(self._due_h, due)
            self._next = sif
        return self._next

    def _send(self, sif: RecordedSif) -> None:
        rec_seq, last = sif.seq, self._last_rec_seq
        gap = 0 if last is None else (rec_seq - last - 1) & 0xFF
        self._last_rec_seq = rec_seq
        t = sif.transducer
        if not self.channels[t.name].enabled:
            self.withheld += 1  # a disabled transducer sends nothing (its loss goes on)
            self._gap += gap
            return
        gap, self._gap = gap + self._gap, 0
        if last is None or self.replay_clock.model.boot_at(sif.log_ns) != self._sif_boot:
            self._sif_total = rec_seq  # a boot's first: as recorded
            self._sif_boot = self.replay_clock.model.boot_at(sif.log_ns)
        else:
            self._sif_total += gap
        seq = self._sif_total & 0xFF
        self._sif_total += 1
        boot = self.replay_clock.model.boot_at(sif.log_ns)
        stamps = [self.replay_clock.board(boot, b) for b in sif.board_us]
        flat = [x for pair in zip(stamps, sif.raw, strict=True) for x in pair]
        frame = encode_frame(SOS, seq, t.id, t.sif_struct.pack(*flat))
        self._sifs.append(frame)
        self.backlog += len(frame)  # (the server sets it again next turn: the link's queue)
        self.sent += 1

    def next_deadline_us(self) -> int | None:
        due: int | None = super().next_deadline_us()
        now = time.monotonic_ns()
        if self.backlog > BACKLOG:
            return due  # (waiting for the host: its input or the server's writability wakes us)
        ready = self._ready_ns()
        if ready is None:
            return due  # (no request yet: its input wakes us)
        if ready > now:  # (the host's lead: wake when it is over)
            wake: int = self.clock() + (ready - now) // 1000
            return wake if due is None else min(due, wake)
        if self.timeline.started and self._peek() is not None:
            wait = (self.timeline.mono_at(self.passes, self._due_h) - now) / 1e3
            mine = self.clock() + max(0, int(wait))
            due = mine if due is None else min(due, mine)
        return due


def _not_reproduced(name: str) -> Callable[[bytes], tuple[int, bytes]]:
    def call(payload: bytes) -> tuple[int, bytes]:
        return 0xFF, f"{name}: not reproduced by a replay (recorded: its name only)".encode()

    return call
