"""The daemon: many boards in, every transducer a typed, time-stamped topic out.

- :mod:`.service` - :class:`Daemon` (fan-out, diagnostics, boards coming and going), ``connect``
- :mod:`.context` - the values and callables a board session is handed instead of the daemon
- :mod:`.claims` - board names and message type names, held daemon-wide
- :mod:`.session` - one board: connect, validate, serve, notice loss, reconnect
- :mod:`.liveness` - whether a board's link is alive, from what is heard (pure, time passed in)
- :mod:`.inflight` - the supervisor's calls to a board: never waited for, one of a kind out
- :mod:`.status` - a session's state (an enum) and status (a dataclass, its JSON keys)
- :mod:`.board_topics` - a board's topics, message types and command topics at each handshake
- :mod:`.fanout` - every topic and update to every publisher, their errors counted
- :mod:`.sample_path` - a sample SIF in, host-timed updates out
- :mod:`.session_clock` - one board's clock sync in its session, its skew kept across links
- :mod:`.prober` - one board's clock probes on its reading thread
- :mod:`.alignment` - the host-time grid of aligned transducers, the board's account of it
- :mod:`.settings` - a board's run-time configuration: the file's keys at connect and reset
- :mod:`.background` - what the supervisor asks for but must not wait for (re-applying keys)
- :mod:`.failsafe` - the host's side of a board's failsafe: keepalive, goodbye, its trip count
- :mod:`.control` - the local control endpoint (``missing-link config``, ``info``, ``call``)
- :mod:`.control_ops` - what that endpoint serves, from three of the daemon's verbs
- :mod:`.actuators` - commands for a board's actuators, latest wins; timed ones at their time
- :mod:`.commands` - who may move the robot: the allow-list, on every path to an actuator
- :mod:`.discovery` - boards found as their serial ports appear (``run --auto``)
- :mod:`.listener`, :mod:`.dialin` - boards that dial in (``run --listen``), each to its session
  by its ``board.id``; :mod:`.listen_spec` - where; :mod:`.session_link` - how a session gets
  its board (by URL, or handed over)
- :mod:`.health` - the daemon's rows besides its boards (publishers, control, listener)
- :mod:`.joints` - the robot-level ``JointState`` in and out (``[joints]``, ros2_control)
- :mod:`.config` - the TOML configuration, validated (its ROS tables: :mod:`.ros_config`)
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:  # (at run time loaded on first use: ``missing-link call`` imports .control only)
    from .config import BoardSpec, Config
    from .service import Daemon, connect
    from .session import BoardSession

_WHERE = {
    "BoardSpec": "config",
    "Config": "config",
    "Daemon": "service",
    "connect": "service",
    "BoardSession": "session",
}

__all__ = ["BoardSession", "BoardSpec", "Config", "Daemon", "connect"]


def __getattr__(name: str) -> Any:
    module = _WHERE.get(name)
    if module is None:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    return getattr(importlib.import_module(f"{__name__}.{module}"), name)
