"""What every standard-type builder shares: the mapping a builder returns, the frame id a
transducer's messages carry (changeable while the daemon runs), the host-side options of one
transducer, SI conversion and the header."""

from __future__ import annotations

import math
import threading
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import Any

from ...descriptors import Transducer

#: a descriptor unit -> the SI unit's factor (REP 103: metres, radians, tesla, seconds)
UNIT_TO_SI = {
    "mm": 0.001, "cm": 0.01, "m": 1.0, "deg": math.pi / 180, "rad": 1.0, "rev": 2 * math.pi,
    "T": 1.0, "uT": 1e-6, "gauss": 1e-4, "G": 1e-4, "us": 1e-6, "ms": 1e-3, "s": 1.0,
}  # fmt: skip
_FRAME_OK = str.isprintable


def si_value(t: Transducer, value: float) -> float:
    """A raw value in SI units: ``(value * scale + offset)`` in the descriptor's unit."""
    scale = float(t.options.get("scale", 1.0))
    offset = float(t.options.get("offset", 0.0))
    return (value * scale + offset) * UNIT_TO_SI.get(t.unit or "", 1.0)


def descriptor_key(t: Transducer, key: str) -> str | None:
    """A key of the descriptor, known to this host or not (``counts_per_rev`` is kept among
    the unknown keys by hosts that predate it)."""
    return t.options.get(key, t.unknown.get(key))


class FrameId:
    """The ``header.frame_id`` of one transducer's standard messages.  Every message reads it
    when it is built, so a change (a ROS 2 parameter, ``Daemon.set_frame_id``) shows in the
    next one; listeners (a face that shows it, e.g. as a parameter) hear every change."""

    def __init__(self, value: str) -> None:
        self.value = check_frame_id(value)
        self.set_at_run_time = False
        self.listeners: list[Callable[[str], None]] = []

    def set(self, value: str) -> None:
        self.value = check_frame_id(value)
        self.set_at_run_time = True
        for fn in list(self.listeners):
            fn(self.value)

    def channel(self, ch: int, chan_count: int) -> str:
        """The frame of one channel: the transducer's, or ``<frame>/<ch>`` when it has several
        (eight IR rangers on one transducer look eight ways)."""
        return self.value if chan_count == 1 else f"{self.value}/{ch}"


def check_frame_id(value: object) -> str:
    if not isinstance(value, str) or not value or not _FRAME_OK(value) or " " in value:
        raise ValueError(f"frame_id {value!r}: a non-empty name without spaces, like base_link")
    return value


class FrameIds:
    """One board's frame ids by transducer name, kept across reconnects: a frame id set while
    the daemon runs survives the board's reconnecting; one that was not follows the config."""

    def __init__(self) -> None:
        self._frames: dict[str, FrameId] = {}
        self._lock = threading.Lock()

    def holder(self, name: str, initial: str) -> FrameId:
        with self._lock:
            f = self._frames.get(name)
            if f is None:
                f = self._frames[name] = FrameId(initial)
            elif not f.set_at_run_time and f.value != initial:
                f.value = check_frame_id(initial)  # (a renamed board, a changed default)
            return f

    def get(self, name: str) -> FrameId | None:
        with self._lock:
            return self._frames.get(name)


@dataclass(frozen=True)
class StdOptions:
    """One transducer's host-side keys (``[boards.<board>.ros.<transducer>]``,
    docs/ros.md): what the board cannot know about where it is mounted."""

    frame_id: str | None = None  #: default: the descriptor's ``frame_id``, else <board>/<name>
    standard: bool = True  #: publish its standard types
    thesis: bool = True  #: publish its thesis-format topic (and take thesis-format commands)
    counts_per_rev: float | None = None  #: an encoder's counts (edges, x4) per revolution
    field_of_view: float | None = None  #: a ranger's, in rad (default: its datasheet's)


@dataclass
class StandardMapping:
    """One standard type of a transducer, published on ``<its topic>/<suffix>``."""

    type_name: str
    suffix: str
    #: (channel, host ns, value) -> CDR: one message per channel that has a value
    build: Callable[[int, int, Any], bytes]
    #: (host ns per channel, values) -> CDR or None (nothing this time): one message per sample
    sample: Callable[[list[int], list[Any]], bytes | None] | None = None
    frame: FrameId | None = None


def no_channel(ch: int, ns: int, value: Any) -> bytes:
    raise ValueError("a per-sample type: built from all channels at once")


@dataclass
class Ctx:
    """What a builder is given for one transducer of one board."""

    board: str
    t: Transducer
    typestore: Any
    frame: FrameId
    options: StdOptions = field(default_factory=StdOptions)
    #: the board's run-time configuration now (``<transducer>.<key>`` -> value)
    settings: Callable[[], Mapping[str, Any]] = dict

    def T(self, type_name: str) -> Any:
        return self.typestore.types[type_name]

    def header(self, ns: int, frame_id: str | None = None) -> Any:
        sec, nsec = divmod(ns, 1_000_000_000)
        Header, Time = self.T("std_msgs/msg/Header"), self.T("builtin_interfaces/msg/Time")
        return Header(stamp=Time(sec=sec, nanosec=nsec), frame_id=frame_id or self.frame.value)

    def cdr(self, msg: Any, type_name: str) -> bytes:
        return bytes(self.typestore.serialize_cdr(msg, type_name))

    def setting(self, key: str, default: Any) -> Any:
        """The transducer's run-time key ``key`` now (the board's configuration), or
        ``default`` (the driver's) when the board has none."""
        return self.settings().get(f"{self.t.name}.{key}", default)

    def joint(self, ch: int) -> str:
        """The joint name of a channel on this transducer's own JointState topic."""
        base = f"{self.board}/{self.t.name}"
        return base if self.t.chan_count == 1 else f"{base}/{ch}"
