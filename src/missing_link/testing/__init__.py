"""What a test of missing-link, or of a program built on it, needs and should not write again
(shipped with the library, as ``trio.testing`` is).

- :class:`FakeClock` (:mod:`.clock`) - the host's clock, standing still until a test advances it
  (``Board``, ``Reactor`` and ``Daemon`` take it as ``clock=``)
- :class:`FakeBoardClock` (:mod:`.board_clock`) - a board's µs clock that a test turns
  (``make_sim(name, clock=...)``, ``BoardRuntime(clock=...)``)
- :func:`call_runtime` (:mod:`.calls`) - a J2A call on a board runtime in this process, its
  answer decoded; :func:`wait_for` - a condition waited for, bounded
- :class:`RuntimeBoard` (:mod:`.runtimes`) - a board under test on any runtime, one interface:
  a host that calls (its answer decoded) and hangs up, a raw line, board time passing;
  :class:`SteppedBoard` (CPython, in this process, on a fake board clock), :class:`ProcessBoard`
  (a board file on CPython), :class:`MicroPythonSim` and :class:`AvrSim` (:mod:`.sims`: the
  firmware in its simulators), :func:`build_avr`
- :mod:`.pytest_plugin` - the fixtures ``board_runtime`` (parametrised over :data:`RUNTIMES`),
  ``start_board``, ``avr_firmware``, ``shared_tmp``: ``pytest_plugins =
  ["missing_link.testing.pytest_plugin"]`` in a conftest.py
"""

from __future__ import annotations

from .board_clock import FakeBoardClock
from .calls import Answer, call_runtime, replies, wait_for
from .clock import FakeClock
from .runtimes import RUNTIMES, TURN_US, ProcessBoard, RuntimeBoard, SteppedBoard
from .sims import AvrSim, MicroPythonSim, build_avr

__all__ = [
    "RUNTIMES",
    "TURN_US",
    "Answer",
    "AvrSim",
    "FakeBoardClock",
    "FakeClock",
    "MicroPythonSim",
    "ProcessBoard",
    "RuntimeBoard",
    "SteppedBoard",
    "build_avr",
    "call_runtime",
    "replies",
    "wait_for",
]
