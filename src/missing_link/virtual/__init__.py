"""Virtual boards: simulated sensor boards that speak real J2A over real links (tests, demos).

- :mod:`.sims` - the boards by name (``thesis``, ``encoder_servo``, ``rangers``, ``rate``,
  ``original``, and the hostile ones); :mod:`.hostile` - hostile and buggy boards
- :mod:`.drivers` - simulated drivers with plausible, seeded signals
- :mod:`.clocks` - board clocks whose truth is known (offset, skew, drift, resets)
- :mod:`.server` - a board runtime served on tcp, unix, a pty or memory
- :mod:`.process` - a virtual board in a process of its own
- :mod:`.boardfile` - any board file as a virtual board on CPython; :mod:`.mpyboard` - the same
  under MicroPython in node; :mod:`.world` - the simulated machine and parts they run on
- :mod:`.faults` - the fault relay (corruption, delay, loss, black hole)
- :mod:`.syncsim` - the clock-sync simulation: link models, anchor methods, runner
- :mod:`.original` - the 2014 firmware's a2jMany, offset bug and all
- :mod:`.recording`, :mod:`.replay`, :mod:`.replay_clock`, :mod:`.replay_serve` - a recording
  played back as the boards that made it (``missing-link replay``)
"""

from .server import BoardServer, start_board_thread
from .sims import SIMS, make_sim

__all__ = ["SIMS", "BoardServer", "make_sim", "start_board_thread"]
