# The firmware a serial board's flash holds, run at power-on as its main.py runs it (the slot
# mlboard/boot.py chooses, the board file there), stepped by serial_board.mjs: its link is the
# port (USB CDC: stdin and stdout), the parts are the simulator's (src/missing_link/virtual/world,
# imported before the flash was mounted).  The break between frames (board/wire.py) stops it as
# on a board: "missing-link firmware stopped: REPL", then the REPL.  A board file whose link is
# not USB would run on a network this harness does not have: the REPL comes up at once.
import sys

import simworld.machine as sim_machine
from simworld.parts import populate

sys.path.insert(0, "/lib")
from mlboard import boot as loader  # noqa: E402 - the root's, as main.py finds it

_chosen = loader.select()
loader.enter(_chosen, "/")
from board import BOARD  # noqa: E402 - the chosen slot's


class PortLink:
    # the firmware's link on the port: bytes in from node, bytes out to it
    def __init__(self):
        self.rx = bytearray()
        self.tx = bytearray()

    def read(self):
        if not self.rx:
            return None
        data = bytes(self.rx[:256])
        self.rx = self.rx[256:]
        return data

    def write(self, data):
        self.tx.extend(data)

    def wait(self, us):
        pass

    def close(self):
        pass


_fw = None
_link = PortLink()
_repl_machine = sys.modules.get("machine")  # (the REPL's: reset, for mpremote)
if BOARD.get("link", {}).get("kind", "usb") == "usb":
    populate(BOARD, ())
    sys.modules["machine"] = sim_machine
    from mlboard.firmware import BreakIn, Firmware  # noqa: E402

    _fw = Firmware(BOARD, sim_machine, _link)


def _fw_running():
    return _fw is not None


def _fw_feed(h):
    _link.rx.extend(bytes.fromhex(h))


def _fw_step():
    # one turn of the firmware: its output as hex, or "BREAK" when it stopped for the REPL
    global _fw
    try:
        _fw.step()
    except BreakIn:
        _fw = None
        sys.modules["machine"] = _repl_machine
        print("missing-link firmware stopped: REPL")
        return "BREAK"
    if not _link.tx:
        return ""  # (MicroPython's b"".hex() is b"", which node cannot take as a string)
    out = bytes(_link.tx).hex()
    _link.tx = bytearray()
    return out
