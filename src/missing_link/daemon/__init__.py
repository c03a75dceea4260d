"""The daemon: many boards in, every transducer a typed, time-stamped topic out.

- :mod:`.service` - :class:`Daemon` (fan-out, diagnostics, boards coming and going), ``connect``
- :mod:`.context` - the values and callables a board session is handed instead of the daemon
- :mod:`.claims` - board names and message type names, held daemon-wide
- :mod:`.session` - one board: connect, validate, serve, notice loss, reconnect
- :mod:`.sample_path` - a sample SIF in, host-timed updates out
- :mod:`.prober` - one board's clock probes on its reading thread
- :mod:`.actuators` - commands for a board's actuators, latest wins
- :mod:`.discovery` - boards found as their serial ports appear (``run --auto``)
- :mod:`.config` - the TOML configuration, validated
"""

from .config import BoardSpec, Config
from .service import Daemon, connect
from .session import BoardSession

__all__ = ["BoardSession", "BoardSpec", "Config", "Daemon", "connect"]
