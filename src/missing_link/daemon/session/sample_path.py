"""One board's sample path: a sample SIF in, host-timed ``Update`` objects out to the daemon's
publishers.  It runs on the board's reading thread (the daemon's I/O loop) for every SIF.

Theory of operation
-------------------
Per SIF:

1. loss: the SIF's seq gives the SIFs lost since the previous one, modulo 256; after an outage
   of the same board boot, the board's own count of SIFs sent (``a2jSifCount``, read at the
   handshake: ``resume``) gives the wraps, so a long outage is counted exactly
   (``outage_lost_sifs``, part of the link's ``lost_sifs``);
2. the payload is decoded with the transducer's descriptor; an unknown transducer or a payload
   that does not fit it is counted (``unknown_sifs``, ``bad_sifs``), never raised;
3. host times: the session's :class:`~missing_link.timesync.ClockSync` maps every stamp.  Before
   the first estimate, and for a stamp far from the map (an outlier: ``clock_outliers``), the
   receive time is used and flagged (``NOT_SYNCED``, ``OUTLIER``).  Nothing is measured after it
   arrived: a mapped time later than the receipt (the map's error, a few µs) is set to the
   receipt (``future_clamps``).  Per topic, host times are strictly increasing
   (``host_time_clamps`` counts the nudges, e.g. several samples read in one go while unsynced).
   An aligned transducer's time is held against its host-time grid (``grid``, set by the
   session from the configuration: alignment.py): one further from its instant than its bound
   allows is flagged ``OFF_GRID`` and counted (``off_grid_samples``);
4. one ``Update`` to every publisher (unless the transducer's thesis-format topic is off:
   ``quiet``), and on each of its standard-type topics (``ros/standard``) one per sample or
   one per channel with a value, as the type is made.

A bug past the decoding (a publisher that raises) is the SIF handler's: the link counts it by
kind and reads on; the SIFs held during a handshake (``resume``) are guarded and counted the
same way, in the session's ``faults``, so a bug never ends a connect.  A handshake that fails
between ``listen`` and ``resume`` leaves its held SIFs to the next ``listen``: taken with that
handshake's when the board did not restart, else counted lost.

A log SIF (the board's log, cmd ``LOG_CMD``) counts in 1 like any SIF, then goes to the board's
log path (``board_log.py``), which hands its lines to ``log``.

The session owns the supervision (connect, serve, reconnect) and sets ``topics``,
``standard`` and ``sync`` at each handshake; this class owns what happens to each sample.  It
knows nothing of the daemon: it is handed ``publish`` (every update goes there) and the offset
from the monotonic clock to the published (realtime) one.
"""

from __future__ import annotations

import logging
import math
import struct
import time
from collections.abc import Callable
from typing import Any

from ...board.log import LOG_CMD
from ...host.board import Board
from ...host.board_log import LogLine
from ...host.sif_handlers import named
from ...j2a import SifReceived
from ...logs import ErrorCounts
from ...ros.standard import StandardMapping
from ...timesync.sync import NOT_SYNCED, OFF_GRID, OUTLIER, ClockSync
from ...topics import Topic, Update
from .alignment import grid_of, off_grid
from .board_log import BoardLogPath
from .board_topics import BoardTopics
from .held_sifs import HeldSifs

log = logging.getLogger(__name__)

#: how far from its grid an aligned sample may lie beyond its clock bound (a board's tick and
#: the map it was handed are that good): more is flagged OFF_GRID
GRID_SLACK_NS = 100_000


class SamplePath:
    def __init__(
        self,
        publish: Callable[[Update], None],
        realtime_offset_ns: int,
        log: Callable[[LogLine], None] = lambda line: None,
        faults: ErrorCounts | None = None,
    ) -> None:
        """``faults``: where a bug on the path is counted when no SIF handler's guard is
        around it (the held SIFs ``resume`` takes: the session's, as the reading thread's)."""
        self.publish = publish
        self.faults = faults if faults is not None else ErrorCounts(logging.getLogger(__name__))
        self.log = BoardLogPath(log, realtime_offset_ns)  #: the board's log (board_log.py)
        self.realtime_offset_ns = realtime_offset_ns
        self.name = ""  #: the board's topic name (for log lines)
        self.sync: ClockSync | None = None  #: the board's clock sync (None: none, receive times)
        self.board: Board | None = None  #: the board of the current connection
        self.topics: dict[int, Topic] = {}  # transducer id -> topic
        #: transducer id -> its standard-type topics (``ros/standard``)
        self.standard: dict[int, list[tuple[Topic, StandardMapping]]] = {}
        self.quiet: set[int] = set()  #: transducers whose thesis-format topic is off
        self.samples = 0
        self.unknown_sifs = 0
        self.bad_sifs = 0
        self.outliers = 0
        self.host_time_clamps = 0
        self.future_clamps = 0  # mapped after their own receipt (map error): set to the receipt
        self.outage_lost_sifs = 0  #: SIFs lost while the link was down (included in lost_sifs)
        #: transducer id -> (period ns, phase ns) of its host-time grid, when it is aligned
        #: (board/timing.py; the session keeps it with the board's configuration)
        self.grid: dict[int, tuple[int, int, int]] = {}
        #: host time (ns) the grid took effect: what was measured before is not held against it
        self.grid_since_ns = 0
        self.off_grid_samples = 0  #: samples of aligned transducers that were not on their grid
        self.next_seq: int | None = None  # after the last SIF seen on this board boot
        #: the board boot (clock epoch) the seq and the count go on from, set at ``resume``:
        #: a handshake that failed before it leaves it, so the next one is not taken as the
        #: same boot (the new boot's SIFs before it would count as lost); the session's test
        self.boot = ""
        self._held_boot = ""  # the board boot of the SIFs held (set at ``listen``)
        self._total: int | None = None  # the next SIF's number since boot (unwrapped seq)
        self._outage_count: int | None = None  # a2jSifCount read after an outage
        self._last_host: dict[int, int] = {}  # transducer id -> newest host ns published
        self._said: set[str] = set()  # standard-type topics whose failure was logged
        self._hold = HeldSifs()  #: SIFs that came between ``listen`` and ``resume``

    def listen(self, board: Board, same_boot: bool) -> None:
        """At a handshake, before the board's count is read (``resume``), with this path's
        handler on the board: the SIFs from here on wait, in order, until ``resume``, so none
        falls between the count and the listening (a replay sends its samples once the count is
        read: docs/recording.md).  ``same_boot``: the seq goes on from the last SIF seen."""
        boot, hold = board.properties.get("clock.epoch", ""), self._hold
        with hold.lock:
            # SIFs held by a handshake that failed before ``resume`` (its count call timed
            # out on a busy host) were never taken: of the same boot they go out with this
            # one's, in order; of a board that restarted meanwhile they are counted lost
            left = hold.sifs or []
            keep = same_boot or (bool(boot) and boot == self._held_boot)
            hold.sifs, self._held_boot = (left if keep else []), boot
            dropped, hold.dropped, last = hold.dropped, 0, hold.last_seq
            if not keep:
                hold.forget_dropped()
        gone = dropped + (0 if keep else len(left))
        if gone:
            self.outage_lost_sifs += gone
            board.link.count_lost_sifs(gone)
        last = left[-1][0].seq if last is None and left else last
        if keep and last is not None:  # (the seq goes on from the last SIF received)
            board.link.expect_sif_seq(last + 1)
        elif same_boot and self.next_seq is not None:
            board.link.expect_sif_seq(self.next_seq)

    def follow(self, values: dict[str, Any]) -> bool:
        """The host-time grid of the board's configuration ``values`` (alignment.py); True
        when the board became aligned just now (it needs the clock map at once)."""
        aligned_before = bool(self.grid)
        grid = grid_of(values, self.topics)
        if grid != self.grid:
            self.grid, self.grid_since_ns = grid, time.time_ns()
        return bool(self.grid) and not aligned_before

    def begin(self, name: str, sync: ClockSync | None, declared: BoardTopics) -> None:
        """A new link's board, named ``name``, its clock ``sync`` (None: none), its topics as
        they are declared (``declared`` is filled on: the first SIF is taken from ``listen`` on)."""
        self.name, self.sync = name, sync
        self.topics, self.standard, self.quiet = declared.topics, declared.standard, declared.quiet

    def resume(self, board: Board, same_boot: bool, count: int | None) -> None:
        """At a handshake, after ``listen``: ``same_boot`` (the board's clock epoch is the one
        before an outage) means the SIFs it sent meanwhile count as lost, modulo 256 from the
        seq, exactly when the board can tell how many it has sent (``count``, from
        ``a2jSifCount``).  The board's log learns the names and reads the board's counts (a
        call: the supervisor's thread).  Then the SIFs held since ``listen``, in order (one
        that comes meanwhile waits for them)."""
        count = self._hold.count_before(count)
        self.board = board
        lg = self.log
        lg.name, lg.sync = self.name, self.sync
        lg.names = {i: t.transducer.name for i, t in self.topics.items()}
        lg.connect(board, board.properties.get("clock.epoch", ""), board.timeout)
        if self.next_seq is not None and same_boot:
            self._outage_count = count
        else:
            self._total = count
            self._outage_count = None
        hold = self._hold
        with hold.lock:
            for sif, now_mono in hold.sifs or ():
                try:
                    self._take(sif, now_mono)
                except Exception as e:  # noqa: BLE001 - as the SIF handler's: never ends a handshake
                    self.faults.caught("SIF handler", e, f"SIF handler {named(self.on_sif)}")
            hold.sifs = None
            # those dropped past HOLD_MAX count lost; the seq and the board's total go on
            # from the last one received
            if hold.dropped:
                self.outage_lost_sifs += hold.dropped
                board.link.count_lost_sifs(hold.dropped)
            if hold.last_seq is not None:
                self.next_seq = hold.last_seq + 1
                self._total = None if self._total is None else self._total + hold.span
            hold.forget_dropped()
        self.boot = board.properties.get("clock.epoch", "")

    def _outage_loss(self, mod: int, total: int) -> int:
        """The first SIF after an outage: the seq gives the loss modulo 256 (``mod``); the
        board's count of SIFs sent (read at the handshake, just before this one) gives the
        wraps."""
        assert self._outage_count is not None
        wraps = max(0, round((self._outage_count - (total + mod)) / 256))
        lost = mod + 256 * wraps
        if wraps:
            board = self.board
            if board is not None:
                board.link.count_lost_sifs(256 * wraps)
        self.outage_lost_sifs += lost
        self._outage_count = None
        return lost

    def counters(self) -> dict[str, Any]:
        return {
            "samples": self.samples,
            "unknown_sifs": self.unknown_sifs,
            "bad_sifs": self.bad_sifs,
            "outage_lost_sifs": self.outage_lost_sifs,
            "clock_outliers": self.outliers,
            "host_time_clamps": self.host_time_clamps,
            "future_clamps": self.future_clamps,
            "off_grid_samples": self.off_grid_samples,
            **self.log.counters(),
        }

    def on_sif(self, sif: SifReceived, now_mono: float) -> None:
        """The SIF handler (the board's reading thread), for every sample (held while a
        handshake is between ``listen`` and ``resume``)."""
        if self._hold.sifs is not None and self._hold.hold(sif, now_mono):
            return
        self._take(sif, now_mono)

    def _take(self, sif: SifReceived, now_mono: float) -> None:
        """One SIF: locals, not attributes, the common sample inline, the rare cases (outage,
        clamps, N/A channels, grids, standard types) in the helpers below."""
        cmd, seq, payload, lost = sif
        self.next_seq = seq + 1
        total = self._total
        if total is not None:
            if self._outage_count is not None:
                lost = self._outage_loss(lost, total)
            self._total = total + 1 + lost
        if cmd == LOG_CMD:
            self.log.on_sif(payload, now_mono)
            return
        topic = self.topics.get(cmd)
        if topic is None:
            self.unknown_sifs += 1
            return
        try:
            board_us, values = topic.transducer.decode_columns(payload)
        except ValueError:
            self.bad_sifs += 1  # board data that does not fit its descriptor: counted
            return
        rt_off = self.realtime_offset_ns
        recv_ns = int(now_mono * 1e9)
        arrived = recv_ns + rt_off  # the receipt, as a published (realtime) host time
        missing = values.count(None)
        sync = self.sync
        got = None
        if sync is not None:
            resets = sync.resets
            got = sync.map_many(board_us, now_mono, rt_off)
            if sync.resets != resets:
                log.warning("%s: sample stamps went back: board reset, map restarted", self.name)
        if got is not None and not got[3] & OUTLIER:
            host_ns, est_error, bound, flags = got
            newest = max(host_ns)
            if newest > arrived or missing or self.grid:
                host_ns, newest, flags = self._held(cmd, values, got, arrived, missing)
        else:  # no clock map (yet), or a stamp far from it: the receive time, flagged
            est_error, bound, flags = -1, -1, NOT_SYNCED
            if got is not None:
                flags |= OUTLIER
                self.outliers += 1  # (the sync wants a probe now: the ticker sends it)
            host_ns = [0 if v is None else arrived for v in values]
            newest = arrived
        if missing < len(values):
            last = self._last_host.get(cmd)
            if last is not None and newest <= last:
                host_ns, newest, bound, est_error = self._nudged(
                    host_ns, newest, last, bound, est_error
                )
            self._last_host[cmd] = newest
            stamp = newest  # the log time: the newest measurement (Update would take max again)
        else:  # all N/A: where the board sent it, not at its arrival (late on a busy machine,
            # it may pass the next one's measurement): just after the topic's last sample, or
            # for its first, when the board assembled it (the stamps of N/A channels), mapped
            stamp = self._all_na_stamp(cmd, got, arrived)
        update = Update.build(
            topic=topic,
            board_us=board_us,
            host_ns=host_ns,
            values=values,
            seq=seq,
            lost=lost,
            recv_ns=recv_ns,
            stamp_ns=stamp,
            bound_ns=bound,
            est_error_ns=est_error,
            clock_flags=flags,
        )
        self.samples += len(values) - missing
        if cmd not in self.quiet:
            self.publish(update)
        for std in self.standard.get(cmd, ()):
            if std[1].sample is not None:
                self._publish_sample_type(std, update)
            else:
                self._publish_per_channel(std, update)

    def _held(
        self,
        cmd: int,
        values: list[Any],
        got: tuple[list[int], int, int, int],
        arrived: int,
        missing: int,
    ) -> tuple[list[int], int, int]:
        """The rare cases of a mapped sample: (host times, the newest, flags)."""
        host_ns, _, bound, flags = got
        newest = max(host_ns)
        # Measured before it arrived: a map error never puts a sample after its receipt.
        if newest > arrived:
            self.future_clamps += 1
            host_ns = [min(h, arrived) for h in host_ns]
            newest = arrived
        if missing:
            host_ns = [0 if v is None else h for h, v in zip(host_ns, values, strict=True)]
            newest = max(host_ns)  # (0 when every channel is N/A)
        grid = self.grid.get(cmd)
        if (
            grid is not None
            and newest >= self.grid_since_ns
            and off_grid(newest, grid, bound, GRID_SLACK_NS)
        ):
            flags |= OFF_GRID
            self.off_grid_samples += 1
        return host_ns, newest, flags

    def _all_na_stamp(
        self, cmd: int, got: tuple[list[int], int, int, int] | None, arrived: int
    ) -> int:
        last = self._last_host.get(cmd)
        if last is not None:
            stamp = self._last_host[cmd] = min(arrived, last + 1)
        elif got is not None and not got[3] & OUTLIER:
            stamp = self._last_host[cmd] = min(arrived, max(got[0]))
        else:
            stamp = arrived  # (no map yet: the next sample's time is its arrival too)
        return stamp

    def _nudged(
        self, host_ns: list[int], newest: int, last: int, bound: int, est_error: int
    ) -> tuple[list[int], int, int, int]:
        """Host times per topic are strictly increasing, whatever the board's stamps: moved
        just past the topic's last one (host times, the newest, bound, estimated error)."""
        shift = last + 1 - newest
        self.host_time_clamps += 1
        if bound >= 0:
            bound += shift  # moved off the map by shift: the bound says so
            est_error = round(math.hypot(est_error, shift))  # ... and the estimate
        return [h + shift if h else 0 for h in host_ns], newest + shift, bound, est_error

    def _publish_sample_type(self, std: tuple[Topic, StandardMapping], update: Update) -> None:
        """A standard type made from every channel at once (Imu, JointState, NavSatFix, ...);
        a builder that has nothing to say this time (a TimeReference off a PPS edge) says None."""
        std_topic, mapping = std
        assert mapping.sample is not None
        host_ns, values = update.host_ns, update.values
        if not any(host_ns):
            return  # every channel N/A: nothing to say
        try:
            cdr = mapping.sample(host_ns, values)
        except (ValueError, OverflowError, struct.error, TypeError):
            self._cannot_carry(std_topic)  # values the standard type cannot carry
            return
        if cdr is None:
            return
        self.publish(
            self._standard_update(std_topic, update, update.board_us, host_ns, values, cdr)
        )

    def _publish_per_channel(self, std: tuple[Topic, StandardMapping], update: Update) -> None:
        """A standard type made per channel (Range, Bool): one message per channel with a value."""
        std_topic, mapping = std
        host_ns = update.host_ns
        for ch, v in enumerate(update.values):
            if v is not None:
                try:
                    cdr = mapping.build(ch, host_ns[ch], v)
                except (ValueError, OverflowError, struct.error):
                    self._cannot_carry(std_topic)  # a value the standard type cannot carry
                    continue
                one = self._standard_update(
                    std_topic, update, [update.board_us[ch]], [host_ns[ch]], [v], cdr
                )
                self.publish(one)

    @staticmethod
    def _standard_update(
        topic: Topic,
        update: Update,
        board_us: list[int],
        host_ns: list[int],
        values: list[Any],
        cdr: bytes,
    ) -> Update:
        """An update on a standard-type topic: its own CDR, the sample's clock figures."""
        return Update.build(
            topic=topic,
            board_us=board_us,
            host_ns=host_ns,
            values=values,
            seq=update.seq,
            lost=0,
            recv_ns=update.recv_ns,
            cdr=cdr,
            bound_ns=update.bound_ns,
            est_error_ns=update.est_error_ns,
            clock_flags=update.clock_flags,
        )

    def _cannot_carry(self, topic: Topic) -> None:
        """A value the standard type cannot carry: counted with the bad SIFs (board data), and
        said once per topic with the reason (an encoder's bug would show there too)."""
        self.bad_sifs += 1
        if topic.name not in self._said:
            self._said.add(topic.name)
            log.warning(
                "%s: a sample %s cannot carry (counted in bad_sifs)",
                self.name,
                topic.type_name,
                exc_info=True,
            )
