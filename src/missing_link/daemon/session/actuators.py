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

A timed command (``Command.at_ns``: a host time to act at; board/timing.py) is not replaced by
a later one: each goes to the board as ``a2jAt`` in arrival order, the board's clock map pushed
first, and the board acts at that host time or refuses (past, beyond what the map vouches for,
no map): refusals are counted and said, and a caller waiting on ``Command.done`` gets them.
One batch of timed commands is out at a time (the map, then its ``a2jAt`` calls, in order).

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

Timed = tuple[Transducer, Any, int, "Future[int] | None"]
#: hands the board the current clock map: the call's future, or None (no map to push)
PushMap = Callable[[], "Future[CallResult] | None"]
#: (board, function, payload) -> the call's future; raises MissingLinkError when not sent
CallFn = Callable[[Board, str, bytes], "Future[CallResult]"]
Outcome = CallResult | MissingLinkError | struct.error


class Actuators:
    def __init__(
        self, wake: Callable[[], None], on_error: Callable[[str], None], call: CallFn | None = None
    ) -> None:
        """``wake()``: a command is pending (wake the supervisor); ``on_error(text)``: a call
        the board refused or a link that failed under it; ``call``: how a call is sent (default
        ``board.call_future``; the session's refuses once the board was told goodbye)."""
        self._call: CallFn = call or (lambda board, name, payload: board.call_future(name, payload))
        self._wake = wake
        self._on_error = on_error
        self._pending: dict[str, tuple[Transducer, Any]] = {}  # latest command per actuator
        self._sending: set[str] = set()  # actuators with a call out
        self._timed: list[Timed] = []
        self._timed_out = False  # a batch of timed commands is out
        self._lock = threading.Lock()
        self._stopping: Callable[[], bool] = lambda: False
        self.commands = 0
        self.command_errors = 0

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
                value = value[0]
            if not t.legal(value):
                raise ValueError(f"{t.name}: {value!r} is not a legal {t.dtype} command")
            with self._lock:
                if timed is None:
                    self._pending[t.name] = (t, value)
                elif len(self._timed) >= MAX_TIMED:
                    raise ValueError(f"{t.name}: {MAX_TIMED} timed commands wait already")
                else:
                    assert timed.at_ns is not None
                    self._timed.append((t, value, timed.at_ns, timed.done))
            self._wake()

        return handle

    def run(self, board: Board, stopping: Callable[[], bool], push_map: PushMap) -> None:
        """Start the board's calls for the pending commands (the supervisor's thread; returns
        at once): the latest per actuator whose previous call was answered, and the timed
        ones when no batch is out (``push_map`` first)."""
        self._stopping = stopping
        with self._lock:
            ready = [(t, v) for name, (t, v) in self._pending.items() if name not in self._sending]
            for t, _v in ready:
                del self._pending[t.name]
                self._sending.add(t.name)
            timed: list[Timed] = []
            if self._timed and not self._timed_out:
                timed, self._timed, self._timed_out = self._timed, [], True
        for t, value in ready:
            self._send(board, t, value)
        if timed:
            self._send_timed(board, timed, push_map)

    def reset(self) -> None:
        """A new link: nothing is out on it (what was out on the old one failed with it)."""
        with self._lock:
            self._sending.clear()
            self._timed_out = False

    # ---- commands now ---------------------------------------------------------------------------
    def _send(self, board: Board, t: Transducer, value: Any) -> None:
        try:
            payload = t.value_struct().pack(value)
            fut = self._call(board, str(t.call), payload)
        except struct.error as e:
            self._sent(t, None)
            self.command_errors += 1
            log.warning("%s: bad command value %r: %s", t.name, value, e)
            return
        except MissingLinkError as e:
            self._sent(t, e)
            return
        fut.add_done_callback(lambda f: self._sent(t, _outcome(board, str(t.call), f)))

    def _sent(self, t: Transducer, got: CallResult | MissingLinkError | None) -> None:
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
        except MissingLinkError as e:
            self._timed_failed(timed, e)
            return
        if fut is None:
            self._send_at(board, timed)
            return

        def pushed(f: Future[CallResult]) -> None:
            got = _outcome(board, "a2jHostMap", f)
            if isinstance(got, MissingLinkError):
                self._timed_failed(timed, got)
            else:
                self._send_at(board, timed)

        fut.add_done_callback(pushed)

    def _send_at(self, board: Board, timed: list[Timed]) -> None:
        """The a2jAt calls of a batch, in order (after the map: maybe on the reading thread)."""
        left = [len(timed)]
        lock = threading.Lock()

        def answered(t: Transducer, at_ns: int, done: Future[int] | None, got: Outcome) -> None:
            self._at_answered(t, at_ns, done, got)
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
                payload = struct.pack("<qB", at_ns, board.index[str(t.call)])
                fut = self._call(board, "a2jAt", payload + t.value_struct().pack(value))
            except (MissingLinkError, struct.error) as e:
                answered(t, at_ns, done, e)
                continue
            fut.add_done_callback(reply_to(t, at_ns, done))

    def _at_answered(
        self, t: Transducer, at_ns: int, done: Future[int] | None, got: Outcome
    ) -> None:
        if isinstance(got, CallResult):
            reply = got.payload
            self.commands += 1
            if done is not None:
                done.set_result(struct.unpack("<Q", reply[:8])[0] if len(reply) >= 8 else -1)
            return
        if not self._stopping():  # (closing: a command cut short is not worth a line)
            self.command_errors += 1
            self._on_error(f"{t.name}: timed command refused: {got}")
            log.warning("%s: timed command at %d refused: %s", t.name, at_ns, got)
        if done is not None:  # (its caller hears it either way)
            done.set_exception(got)

    def _timed_failed(self, timed: list[Timed], e: MissingLinkError) -> None:
        for _t, _v, _at, done in timed:
            if done is not None:
                done.set_exception(e)
        self._batch_done()

    def _batch_done(self) -> None:
        with self._lock:
            self._timed_out = False
            more = bool(self._timed)
        if more:
            self._wake()


def _outcome(board: Board, name: str, fut: Future[CallResult]) -> CallResult | MissingLinkError:
    """The reply when the call returned 0, else the error (as ``call_ok`` would raise it)."""
    try:
        result = fut.result()
    except MissingLinkError as e:
        return e
    if result.code != 0:
        return FunctionFailed(board.name, name, result.code, result.payload)
    return result
