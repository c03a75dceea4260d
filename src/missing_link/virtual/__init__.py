"""Virtual boards: simulated sensor boards that speak real J2A over real links (tests, demos)."""

from .server import BoardServer, start_board_thread
from .sims import SIMS, make_sim

__all__ = ["SIMS", "BoardServer", "make_sim", "start_board_thread"]
