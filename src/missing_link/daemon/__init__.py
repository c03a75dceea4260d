"""The daemon: many boards in, every transducer a typed, time-stamped topic out.

Its rooms, from the top down (each imports only the ones below it: tests/test_architecture.py):

- :mod:`.service` - :class:`Daemon` (diagnostics, boards coming and going), ``connect``
- :mod:`.board_api` - its verbs on one board (call, configure, ...), by name or URL
- :mod:`.fanout` - every topic and update to every publisher, their errors counted
- :mod:`.health` - the daemon's rows besides its boards (publishers, control, listener)
- :mod:`.joints` - the robot-level ``JointState`` in and out (``[joints]``, ros2_control)
- :mod:`.intake` - boards coming in: found as their ports appear (``run --auto``), dialing in
  (``run --listen``), each handed to its session by its ``board.id``
- :mod:`.control` - who steers: the local control endpoint (``missing-link config``, ``info``,
  ``call``) and what it serves, firmware updates, the commands allow-list
- :mod:`.session` - one board: connect, validate, serve, notice loss, reconnect; its sample path,
  clock sync, actuators, run-time configuration, liveness, failsafe, log, memory and status
- :mod:`.config` - the TOML configuration, validated (its ROS tables: :mod:`.ros_config`; where
  to listen: :mod:`.listen_spec`; which ports to probe: :mod:`.discover_spec`; the runtime
  directory: :mod:`.paths`)
- :mod:`.claims` - board names and message type names, held daemon-wide
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from ..lazy import lazy_names

if TYPE_CHECKING:  # (at run time loaded on first use: ``missing-link call`` imports .control only)
    from .config import BoardSpec, Config
    from .service import Daemon, connect
    from .session.session import BoardSession

_WHERE = {
    "BoardSpec": "config",
    "Config": "config",
    "Daemon": "service",
    "connect": "service",
    "BoardSession": "session.session",
}

__all__ = ["BoardSession", "BoardSpec", "Config", "Daemon", "connect"]


__getattr__ = lazy_names(__name__, _WHERE, globals())
