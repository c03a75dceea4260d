"""A board's actuator commands: checked where they arrive, the latest per actuator kept, and
sent to the board by the session's supervisor (never on a face's thread), never waited for.

Any face (the bus, Zenoh, rclpy, rospy) hands a command to the handler of its actuator; the
handler checks it against the transducer's data type, keeps it as the latest for that actuator
(an older one not yet sent is replaced: a servo wants the newest position, not a backlog) and
wakes the supervisor, which starts the actuator's function (``call=`` in its descriptor) with
it.  Each actuator has at most one call out at a time: a newer command waits (and is replaced)
until the board has answered the previous one, whose answer wakes the supervisor again.  The
supervisor never waits for an answer: it must see a frozen board in time (liveness.py), and
the link sends one request at a time, so a wait would be behind whatever is queued.  A refused
call is counted and said once per failure, never raised into a face.

A value meets its type where it arrives: the handler packs it as the descriptor's data type says
(``Transducer.pack_command``: a float32 beyond 3.4028235e38, NaN, an infinity, an integer beyond
its width or signedness, the N/A value are refused there), so what waits is bytes the board can
take and nothing later can fail to pack.  A refused value is counted (``values_refused``: the
status and ``/diagnostics``), said once per actuator, and raised to the face as ValueError (the
face counts it too); it never reaches the board's queue.  Whatever a call raises on the way out
is caught where it is started: no command ends the supervisor, and a batch of timed commands
always ends (one that could not be packed left the timed path stuck for good before: "64 timed
commands wait already").

A timed command (``Command.at_ns``: a host time to act at; board/timing.py) is not replaced by
a later one: each goes to the board as ``a2jAt`` in arrival order, the board's clock map pushed
first, and the board acts at that host time or refuses (past, beyond what the map vouches for,
no map): refusals are counted and said, and a caller waiting on ``Command.done`` gets them.
One batch of timed commands is out at a time (the map, then its ``a2jAt`` calls, in order).
The board acts at the tick the map it was given puts at the asked time: as close to that time
as that map's hard bound there (``within``, kept for the newest one taken: ``timed_within_ns``),
which the estimate may have narrowed and moved by the time the action's sample is mapped.

Every call goes through ``call`` (the session's ``Farewell.call_future``): once the board has
been told goodbye, none reaches it - not a command the supervisor was starting as the daemon
stopped, not the ``a2jAt`` of a batch whose map was answered after the goodbye (it used to go
out from that answer's callback, and the board acted on it with no host left).
"""

from __future__ import annotations

import logging
import struct
import threading
from collections.abc import Callable
from concurrent.futures import Future
from typing import Any

from ...descriptors import Transducer
from ...errors import FunctionFailed, MissingLinkError
from ...host.board import Board
from ...host.link import CallResult
from ...topics import Command, Update

log = logging.getLogger(__name__)

MAX_TIMED = 64  #: timed commands waiting for the supervisor, per board

Timed = tuple[Transducer, bytes, int, "Future[int] | None"]  #: (its payload, at, done)
#: hands the board the current clock map: the call's future, or None (no map to push)
PushMap = Callable[[], "Future[CallResult] | None"]
#: (board, function, payload) -> the call's future; raises MissingLinkError when not sent
CallFn = Callable[[Board, str, bytes], "Future[CallResult]"]
Outcome = CallResult | Exception


class Actuators:
    def __init__(
        self,
        wake: Callable[[], None],
        on_error: Callable[[str], None],
        call: CallFn | None = None,
        within: Callable[[int], int | None] = lambda tick: None,
    ) -> None:
        """``wake()``: a command is pending (wake the supervisor); ``on_error(text)``: a call
        the board refused or a link that failed under it; ``call``: how a call is sent (default
        ``board.call_future``; the session's refuses once the board was told goodbye);
        ``within(tick)``: how close to its asked host time a timed call due at board ``tick``
        acts (ns: the hard bound there of the map the board was given; None: unknown)."""
        self._call: CallFn = call or (lambda board, name, payload: board.call_future(name, payload))
        self._within = within
        #: the newest timed command the board took acts this close to its asked time (ns)
        self.timed_within_ns: int | None = None
        self._wake = wake
        self._on_error = on_error
        self._pending: dict[str, tuple[Transducer, bytes]] = {}  # latest payload per actuator
        self._sending: set[str] = set()  # actuators with a call out
        self._timed: list[Timed] = []
        self._timed_out = False  # a batch of timed commands is out
        self._lock = threading.Lock()
        self._stopping: Callable[[], bool] = lambda: False
        self.commands = 0
        self.command_errors = 0
        self.values_refused = 0  #: values their actuator's type cannot hold (never queued)
        self._said: set[str] = set()  # actuators whose refused value was said

    def handler(self, t: Transducer) -> Callable[[Any], None]:
        """The command handler for actuator ``t``: raises ValueError for a value it cannot
        take (the face counts it), else queues it (latest wins) and wakes the supervisor."""

        def handle(value: Any) -> None:
            timed: Command | None = None
            if isinstance(value, Command):
                timed = value if value.at_ns is not None else None
                value = value.values
            if isinstance(value, Update):
                present = [v for v in value.values if v is not None]
                if not present:
                    raise ValueError(f"{t.name}: the update on {value.topic.name} has no value")
                value = present[0]
            elif isinstance(value, (list, tuple)):
                value = value[0] if value else None
            payload = self._packed(t, value)
            at = timed.at_ns if timed is not None else None
            if at is not None and not (_number(at) and 0 <= at < 1 << 63):  # (NaN, inf: out)
                raise ValueError(f"{t.name}: at {at!r:.40}: not a host time (int64 ns)")
            with self._lock:
                if timed is None:
                    self._pending[t.name] = (t, payload)
                elif len(self._timed) >= MAX_TIMED:
                    raise ValueError(f"{t.name}: {MAX_TIMED} timed commands wait already")
                else:
                    assert timed is not None and at is not None
                    self._timed.append((t, payload, int(at), timed.done))
            self._wake()

        return handle

    def _packed(self, t: Transducer, value: Any) -> bytes:
        try:
            return t.pack_command(value)
        except ValueError as e:
            with self._lock:
                self.values_refused += 1
                first = t.name not in self._said
                self._said.add(t.name)
            if first:  # (counted always; said once per actuator)
                log.warning("%s (refused, not sent; further ones are counted only)", e)
            raise

    def run(self, board: Board, stopping: Callable[[], bool], push_map: PushMap) -> None:
        """Start the board's calls for the pending commands (the supervisor's thread; returns
        at once): the latest per actuator whose previous call was answered, and the timed
        ones when no batch is out (``push_map`` first)."""
        self._stopping = stopping
        with self._lock:
            ready = [(t, p) for name, (t, p) in self._pending.items() if name not in self._sending]
            for t, _v in ready:
                del self._pending[t.name]
                self._sending.add(t.name)
            timed: list[Timed] = []
            if self._timed and not self._timed_out:
                timed, self._timed, self._timed_out = self._timed, [], True
        for t, payload in ready:
            self._send(board, t, payload)
        if timed:
            self._send_timed(board, timed, push_map)

    def reset(self) -> None:
        """A new link: nothing is out on it (what was out on the old one failed with it)."""
        with self._lock:
            self._sending.clear()
            self._timed_out = False
        self.timed_within_ns = None  # (the map it was for went with the link)

    # ---- commands now ---------------------------------------------------------------------------
    def _send(self, board: Board, t: Transducer, payload: bytes) -> None:
        try:
            fut = self._call(board, str(t.call), payload)
        except Exception as e:  # noqa: BLE001 - a MissingLinkError, or a bug: never the supervisor's end
            self._sent(t, e)
            return
        fut.add_done_callback(lambda f: self._sent(t, _outcome(board, str(t.call), f)))

    def _sent(self, t: Transducer, got: Outcome | None) -> None:
        """(the reading thread) An actuator's call was answered, or failed (None: never sent)."""
        with self._lock:
            self._sending.discard(t.name)
            more = t.name in self._pending
        if isinstance(got, CallResult):
            self.commands += 1
        elif got is None:
            pass  # (counted where it failed)
        elif not self._stopping():  # closing: a command cut short is not worth a line
            self.command_errors += 1
            self._on_error(str(got))
            log.warning("%s", got)
        if more:
            self._wake()  # the newer command now

    # ---- timed commands -----------------------------------------------------------------------
    def _send_timed(self, board: Board, timed: list[Timed], push_map: PushMap) -> None:
        try:
            fut = push_map()
        except Exception as e:  # noqa: BLE001 - (as _send: the batch ends either way)
            self._timed_failed(timed, e)
            return
        if fut is None:
            self._send_at(board, timed)
            return

        def pushed(f: Future[CallResult]) -> None:
            got = _outcome(board, "a2jHostMap", f)
            if isinstance(got, Exception):
                self._timed_failed(timed, got)
            else:
                self._send_at(board, timed)

        fut.add_done_callback(pushed)

    def _send_at(self, board: Board, timed: list[Timed]) -> None:
        """The a2jAt calls of a batch, in order (after the map: maybe on the reading thread)."""
        left = [len(timed)]
        lock = threading.Lock()

        def answered(t: Transducer, at_ns: int, done: Future[int] | None, got: Outcome) -> None:
            try:
                self._at_answered(t, at_ns, done, got)
            finally:  # (the batch ends whatever the answer did: the timed path is never stuck)
                with lock:
                    left[0] -= 1
                    last = left[0] == 0
                if last:
                    self._batch_done()

        def reply_to(
            t: Transducer, at_ns: int, done: Future[int] | None
        ) -> Callable[[Future[CallResult]], None]:
            return lambda f: answered(t, at_ns, done, _outcome(board, "a2jAt", f))

        for t, value, at_ns, done in timed:
            try:
                if "a2jAt" not in board.index:
                    raise MissingLinkError(f"{board.name}: no a2jAt: it cannot act at a time")
                if str(t.call) not in board.index:  # (a board that changed under the queue)
                    raise MissingLinkError(f"{board.name}: no function {t.call} any more")
                payload = struct.pack("<qB", at_ns, board.index[str(t.call)])
                fut = self._call(board, "a2jAt", payload + value)
            except Exception as e:  # noqa: BLE001 - (as _send: each is answered, the batch ends)
                answered(t, at_ns, done, e)
                continue
            fut.add_done_callback(reply_to(t, at_ns, done))

    def _at_answered(
        self, t: Transducer, at_ns: int, done: Future[int] | None, got: Outcome
    ) -> None:
        if isinstance(got, CallResult):
            reply = got.payload
            self.commands += 1
            tick = struct.unpack("<Q", reply[:8])[0] if len(reply) >= 8 else -1
            self.timed_within_ns = self._within(tick) if tick >= 0 else None
            if done is not None and not done.done():  # (a caller may have cancelled it)
                done.set_result(tick)
            return
        if not self._stopping():  # (closing: a command cut short is not worth a line)
            self.command_errors += 1
            self._on_error(f"{t.name}: timed command refused: {got}")
            log.warning("%s: timed command at %d refused: %s", t.name, at_ns, got)
        if done is not None and not done.done():  # (its caller hears it either way)
            done.set_exception(got)

    def _timed_failed(self, timed: list[Timed], e: Exception) -> None:
        try:
            for _t, _v, _at, done in timed:
                if done is not None and not done.done():
                    done.set_exception(e)
        finally:
            self._batch_done()

    def _batch_done(self) -> None:
        with self._lock:
            self._timed_out = False
            more = bool(self._timed)
        if more:
            self._wake()


def _outcome(board: Board, name: str, fut: Future[CallResult]) -> CallResult | Exception:
    """The reply when the call returned 0, else the error (as ``call_ok`` would raise it)."""
    try:
        result = fut.result()
    except Exception as e:  # noqa: BLE001 - a MissingLinkError, or whatever failed the call
        return e
    if result.code != 0:
        return FunctionFailed(board.name, name, result.code, result.payload)
    return result


def _number(x: object) -> bool:
    return isinstance(x, (int, float)) and not isinstance(x, bool)
