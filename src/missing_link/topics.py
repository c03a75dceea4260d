"""Topics and updates: what the daemon hands to every publisher.

An ``Update`` is one SIF of one transducer: per channel the board stamp, the host time and the
value (None for N/A), plus the clock map's hard error bound and estimated error for those host
times.  Its CDR form is
computed once, on first use, and shared by every publisher that needs it (MCAP, Zenoh,
Foxglove)."""

from __future__ import annotations

import re
from concurrent.futures import Future
from dataclasses import dataclass, field
from typing import Any, NamedTuple

from .descriptors import Transducer
from .ros.msgs import CdrEncoder, msgdef, type_name
from .ros.standard import FrameId

TOPIC_RE = re.compile(r"(/[A-Za-z_][A-Za-z0-9_]*)+\Z")


def check_topic(name: str) -> str:
    """ROS-compatible absolute topic name (tokens may not start with a digit)."""
    if not TOPIC_RE.match(name):
        raise ValueError(f"{name!r} is not a topic name like /board/sensor")
    return name


@dataclass(eq=False)
class Topic:
    name: str
    board: str
    transducer: Transducer
    type_name: str
    msgdef: str
    encoder: CdrEncoder | None = field(repr=False)  #: None: updates bring their own CDR
    standard: bool = False  #: a standard ROS type (already known to every typestore)
    #: a standard type's frame id, changeable while it runs (a face may offer it: ROS 2
    #: parameters); None: none (thesis-format topics, commands)
    frame: FrameId | None = field(default=None, repr=False)

    @classmethod
    def for_transducer(
        cls, name: str, board: str, t: Transducer, package: str, type_name_: str | None = None
    ) -> Topic:
        """``type_name_``: the message type (default ``<package>/msg/<CamelName>``; the daemon
        qualifies it by board where two boards define one name differently)."""
        return cls(
            check_topic(name),
            board,
            t,
            type_name_ or type_name(t, package),
            msgdef(t, 2),
            CdrEncoder(t),
        )

    def register_type(self, typestore: Any) -> None:
        """Make this topic's type known to a rosbags typestore (standard types already are)."""
        if not self.standard and self.type_name not in typestore.types:
            from rosbags.typesys import get_types_from_msg

            typestore.register(get_types_from_msg(self.msgdef, self.type_name))

    @classmethod
    def standard_type(
        cls,
        name: str,
        board: str,
        t: Transducer,
        type_name: str,
        typestore: Any,
        frame: FrameId | None = None,
    ) -> Topic:
        text, _ = typestore.generate_msgdef(type_name, ros_version=2)
        return cls(check_topic(name), board, t, type_name, text, None, standard=True, frame=frame)


class Command(NamedTuple):
    """An actuator command as a face hands it to the daemon: the values (the first one is the
    command) and, for a timed command, the host time (CLOCK_REALTIME ns) to act at; ``done``,
    when given, gets the board tick it will act at, or the board's refusal (``Daemon.send``).

    A thesis-format command message carries its execution time as ``times[0]`` (ROS 2, Zenoh,
    ROS 1): a time in the future makes a timed command; zero or a time already past (a message
    stamped when it was made, as ROS messages usually are) means now."""

    values: list[Any]
    at_ns: int | None = None
    done: Future[int] | None = None

    @classmethod
    def from_message(cls, msg: Any, now_ns: int) -> Command:
        """A thesis-format message decoded by rosbags (ROS 2: ``Time`` with sec and nanosec;
        ROS 1: with sec and nsec too), arrived at ``now_ns`` (CLOCK_REALTIME)."""
        values = [v.item() if hasattr(v, "item") else v for v in msg.values]
        times = list(msg.times)
        at = 0
        if times:
            t = times[0]
            at = int(t.sec) * 1_000_000_000 + int(getattr(t, "nanosec", getattr(t, "nsec", 0)))
        return cls(values, at if at > now_ns else None)


_new_update = object.__new__


class Update:
    """One sample SIF, decoded.  Built by keyword, with :meth:`build` only (``Update(...)``
    takes no arguments), so a board stamp and a host time can never swap places silently."""

    __slots__ = (
        "_cdr",
        "board_us",
        "bound_ns",
        "clock_flags",
        "est_error_ns",
        "host_ns",
        "lost",
        "recv_ns",
        "seq",
        "stamp_ns",
        "topic",
        "values",
    )

    _cdr: bytes | None  #: the CDR form, made on first use (``cdr``)
    topic: Topic
    board_us: list[int]  #: the board's stamp per channel (µs)
    host_ns: list[int]  #: CLOCK_REALTIME ns per channel; 0 where the value is N/A
    values: list[Any]  #: None where the board sent N/A
    seq: int
    lost: int
    recv_ns: int  #: CLOCK_MONOTONIC ns when the SIF arrived (for latency)
    #: host time (CLOCK_REALTIME ns) recorders log it at: the newest measurement in it, or
    #: the mapped arrival time when every channel is N/A
    stamp_ns: int
    #: hard bound: every host time in this update is within ±bound_ns of the truth, as far
    #: as the clock map can tell (-1: unknown, see clock_flags)
    bound_ns: int
    #: statistical: the typical size of the host times' error, about one sigma, calibrated
    #: against known board clocks (weight measurements with it; -1: unknown)
    est_error_ns: int
    #: missing_link.timesync.STEP (the clock map stepped here: start or board reset) |
    #: NOT_SYNCED (no clock map: host time is the receive time)
    clock_flags: int

    @classmethod
    def build(
        cls,
        *,
        topic: Topic,
        board_us: list[int],
        host_ns: list[int],
        values: list[Any],
        seq: int,
        lost: int,
        recv_ns: int,
        cdr: bytes | None = None,
        stamp_ns: int | None = None,
        bound_ns: int = -1,
        est_error_ns: int = -1,
        clock_flags: int = 0,
    ) -> Update:
        """The one constructor (keyword arguments only).  A classmethod rather than a keyword
        ``__init__``: CPython 3.11 calls a class with 12 keywords in ~0.5 µs, this in ~0.25 µs,
        as a positional call was (the sample path makes one or more per SIF)."""
        self = _new_update(cls)
        self.topic = topic
        self.board_us = board_us
        self.host_ns = host_ns
        self.values = values
        self.seq = seq
        self.lost = lost
        self.recv_ns = recv_ns
        self._cdr = cdr
        self.stamp_ns = stamp_ns if stamp_ns is not None else max(host_ns)
        self.bound_ns = bound_ns
        self.est_error_ns = est_error_ns
        self.clock_flags = clock_flags
        return self

    @property
    def sigma_ns(self) -> int:
        """The estimated error's earlier name (``est_error_ns``)."""
        return self.est_error_ns

    @property
    def cdr(self) -> bytes:
        if self._cdr is None:
            assert self.topic.encoder is not None, "standard-type updates carry their CDR"
            self._cdr = self.topic.encoder.encode(self.host_ns, self.values)
        return self._cdr

    def to_json(self) -> dict[str, Any]:
        return {
            "topic": self.topic.name,
            "board_us": self.board_us,
            "host_ns": self.host_ns,
            "values": self.values,
            "seq": self.seq,
            "lost": self.lost,
            "bound_ns": self.bound_ns,
            "est_error_ns": self.est_error_ns,
            "clock_flags": self.clock_flags,
        }

    def __repr__(self) -> str:
        return f"<Update {self.topic.name} {self.values}>"
