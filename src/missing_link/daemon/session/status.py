"""What a board session reports: its state (an enum) and its status (a dataclass).

``SessionState`` is a ``str`` enum, so a state compares equal to its old string (``"up"``) and
goes into JSON as that string.  ``SessionStatus`` is one session's status at one moment, typed;
``to_json()`` gives the plain dict that ``Daemon.status()``, ``/diagnostics``, the ``run``
summary and the live view read, with the keys (and their order) documented for them: the
session's own, the link's counters, the sample path's, the commands', the errors caught (by
kind: ``errors``, ``error_kinds``), the board's identity (``board_id``, ``fw_version``,
``fw_hash``, ``address``), the run-time configuration's, the alignment's, the failsafe's, the
board's memory, the clock sync's and, once a firmware update ran, ``update`` (``{state, done,
total, from, to}``: daemon/control/updates.py).  The parts that other modules own (sample path,
settings, clock sync) stay the plain dicts those modules give.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import asdict, dataclass, field, fields
from enum import IntEnum, StrEnum
from typing import Any, ClassVar

from ...host.results import LinkStats


class SessionState(StrEnum):
    """Where a session's supervisor is (session.py, "Theory of operation")."""

    CONNECTING = "connecting"
    UP = "up"
    BACKOFF = "backoff"
    STOPPED = "stopped"


class Level(IntEnum):
    """Diagnostic levels (diagnostic_msgs/DiagnosticStatus)."""

    OK = 0
    WARN = 1
    ERROR = 2


#: a link's counters in a session's status (host/results.py's LinkStats, summed over its links),
#: in the status's key order; then the transport's own
LINK_KEYS = ("frames", "bad_checksums", "bad_escapes", "cut_frames", "junk_bytes", "lost_sifs",
             "timeouts", "late_replies", "unheard_sifs")  # fmt: skip


def link_json(stats: LinkStats) -> dict[str, int]:
    return {**{k: getattr(stats, k) for k in LINK_KEYS}, **dict(sorted(stats.transport.items()))}


class _Account:
    """A board's own account of something, read by a call: its figures once read, or the
    ``problem`` (under ``PROBLEM_KEY``) when its reply made no sense."""

    PROBLEM_KEY: ClassVar[str]
    problem: str

    def to_json(self) -> dict[str, Any]:
        return {self.PROBLEM_KEY: self.problem} if self.problem else self.figures()

    def figures(self) -> dict[str, Any]:
        raise NotImplementedError


@dataclass(frozen=True)
class FailsafeStatus(_Account):
    """The board's own count of failsafe trips (``a2jFailsafe``), once read; ``problem`` when
    its reply made no sense."""

    PROBLEM_KEY = "failsafe"
    trips: int | None = None
    last_trip_ms: int | None = None
    problem: str = ""

    def figures(self) -> dict[str, Any]:
        if self.trips is None:
            return {}
        return {"failsafe_trips": self.trips, "failsafe_last_trip_ms": self.last_trip_ms}


@dataclass(frozen=True)
class AlignInfo(_Account):
    """The board's account of its grid (``a2jAlignInfo``), once read; ``problem`` when its
    reply made no sense."""

    PROBLEM_KEY = "align_info"
    map_valid: bool | None = None
    map_age_ms: int | None = None
    unaligned_samples: int = 0
    timed_done: int = 0
    timed_refused: int = 0
    #: free-running measurements put off for an instant, polls that reached one (pacing.py;
    #: None: a board that does not say, an AVR board)
    polls_deferred: int | None = None
    poll_overlaps: int | None = None
    problem: str = ""

    def figures(self) -> dict[str, Any]:
        if self.map_valid is None:
            return {}
        out: dict[str, Any] = {
            "map_valid": self.map_valid,
            "map_age_ms": self.map_age_ms,
            "unaligned_samples": self.unaligned_samples,
            "timed_done": self.timed_done,
            "timed_refused": self.timed_refused,
        }
        if self.polls_deferred is not None:
            out["polls_deferred"] = self.polls_deferred
            out["poll_overlaps"] = self.poll_overlaps
        return out


@dataclass(frozen=True)
class MemoryStatus(_Account):
    """The board's own memory figures (``a2jMemory``, board_memory.py), once read; ``problem``
    when its reply made no sense.  A MicroPython board says its heap (bytes free now and at the
    lowest, allocated) and its garbage collections (how many, the longest and the last in µs,
    how many reached an instant it had to be on time for, how many it put off for one); an AVR
    board its stack (bytes never touched since boot, of how many) and its static RAM."""

    PROBLEM_KEY = "memory"
    heap_free: int | None = None
    heap_free_low: int | None = None
    heap_alloc: int | None = None
    gc_collections: int | None = None
    gc_longest_us: int | None = None
    gc_last_us: int | None = None
    gc_overlaps: int | None = None
    gc_deferred: int | None = None
    stack_free_low: int | None = None
    stack_size: int | None = None
    ram_static: int | None = None
    ram_size: int | None = None
    problem: str = ""

    def figures(self) -> dict[str, Any]:
        return {
            f.name: getattr(self, f.name)
            for f in _MEMORY_FIELDS
            if getattr(self, f.name) is not None
        }


_MEMORY_FIELDS = tuple(f for f in fields(MemoryStatus) if f.name != "problem")


@dataclass(frozen=True)
class Identity:
    """Who the board is and what it runs (its properties ``board.id``, ``fw.version``,
    ``fw.hash``: docs/hardware.md, "Identity"), and where it is connected now (its link's URL:
    a board that dials in comes from an address of its own each time)."""

    board_id: str = ""
    fw_version: str = ""
    fw_hash: str = ""
    address: str = ""

    @classmethod
    def of(cls, properties: Mapping[str, str], address: str) -> Identity:
        """From a board's properties; a board without ``board.id`` (the 2014 firmware) is
        known by its ``board.serial``."""
        return cls(
            board_id=properties.get("board.id") or properties.get("board.serial", ""),
            fw_version=properties.get("fw.version", ""),
            fw_hash=properties.get("fw.hash", ""),
            address=address,
        )

    def to_json(self) -> dict[str, str]:
        return asdict(self)  # (its fields are its JSON keys, in order)


def session_level(
    state: SessionState, error: str, warnings: list[str], faults: int
) -> tuple[Level, str]:
    """A session's diagnostic level and message: ERROR when not up, WARN when up with
    warnings or bugs caught, else OK."""
    if state is not SessionState.UP:
        return Level.ERROR, error or state.value
    if warnings:
        return Level.WARN, "; ".join(warnings)
    if faults:  # (a bug caught: up, but not as it should be)
        return Level.WARN, f"up; {faults} errors caught (error_kinds)"
    return Level.OK, "up"


@dataclass(frozen=True)
class SessionStatus:
    """One board session's status; counters are cumulative over every connection."""

    board: str
    url: str
    state: SessionState
    level: Level
    message: str
    error: str
    serial: str
    connects: int
    failures: int
    stale_links: int
    link: LinkStats  #: summed over every link (``link_json``: its keys)
    samples: Mapping[str, Any]  #: the sample path's counters (sample_path.py)
    commands: int
    command_errors: int
    values_refused: int  #: commands whose value their actuator's type cannot hold (actuators.py)
    #: how close to its asked time the newest timed command acts (the board's map's hard bound
    #: at its tick, ns; None: none yet): actuators.py
    timed_within_ns: int | None
    errors: Mapping[str, Any]  #: bugs caught, by kind (``ErrorCounts.to_json``)
    rtt_us: int | None
    warnings: str
    clock_epoch: str
    map_pushes: int
    config: Mapping[str, Any]  #: the run-time configuration's (run_config.py)
    aligned: str  #: the transducers sampled on the host-time grid, by name
    align_info: AlignInfo = field(default_factory=AlignInfo)  #: shown while anything is aligned
    failsafe: FailsafeStatus = field(default_factory=FailsafeStatus)
    memory: MemoryStatus = field(default_factory=MemoryStatus)  #: the board's (a2jMemory)
    sync: Mapping[str, Any] | None = None  #: the clock sync's (None: the board has no clock)
    identity: Identity = field(default_factory=Identity)  #: as of the latest handshake
    #: the last firmware update's state (control/updates.py)
    update: Mapping[str, Any] | None = None

    def to_json(self) -> dict[str, Any]:
        """The plain dict, in the documented key order (JSON types only)."""
        return {
            "board": self.board,
            "url": self.url,
            "state": self.state.value,
            "level": int(self.level),
            "message": self.message,
            "error": self.error,
            "serial": self.serial,
            "connects": self.connects,
            "failures": self.failures,
            "stale_links": self.stale_links,
            **link_json(self.link),
            **self.samples,
            "commands": self.commands,
            "command_errors": self.command_errors,
            "values_refused": self.values_refused,
            "timed_within_us": _us_up(self.timed_within_ns),
            **self.errors,
            "rtt_us": self.rtt_us,
            "warnings": self.warnings,
            "clock_epoch": self.clock_epoch,
            **self.identity.to_json(),
            "map_pushes": self.map_pushes,
            **self.config,
            "aligned": self.aligned,
            **(self.align_info.to_json() if self.aligned else {}),
            **self.failsafe.to_json(),
            **self.memory.to_json(),
            **(self.sync if self.sync is not None else {"sync_state": "none"}),
            **({"update": dict(self.update)} if self.update is not None else {}),
        }


def _us_up(ns: int | None) -> int | None:
    """Whole µs, rounded up (a bound stays a bound)."""
    return None if ns is None else -(-ns // 1000)
