# The simulator's side inside MicroPython: the firmware from the board file on a link whose bytes
# the node host moves, with the world's devices created from the same board file.
# _feed(hex) hands received bytes to the link, _tick() runs one firmware step and returns the
# bytes to send (hex), _ctl(src) runs test code against WORLD and returns repr() of `result`
# (reboot() restarts the firmware on the same filesystem and devices).

import machine
from board import BOARD
from machine import MPU6050, SRF02, WORLD
from mlboard.firmware import BreakIn, Firmware


class SimLink:
    def __init__(self):
        self.rx = bytearray()
        self.tx = bytearray()

    def read(self):
        if not self.rx:
            return None
        data = bytes(self.rx)
        self.rx = bytearray()
        return data

    def write(self, data):
        self.tx.extend(data)

    def wait(self, us):
        pass

    def close(self):
        pass


def _populate(board):
    buses = board.get("buses", {})
    for t in board["transducers"]:
        drv = t["driver"]
        if drv == "sharp_gp2y0a02":
            WORLD.sharp[t["pin"]] = 800
        elif drv in ("srf02", "mpu6050"):
            bus = buses[t["bus"]].get("id", 0)
            if drv == "srf02":
                SRF02(bus, t.get("address", 0x70))
            else:
                MPU6050(bus, t.get("address", 0x68))


_populate(BOARD)
link = SimLink()
fw = Firmware(BOARD, machine, link)
rt = fw.runtime
stopped = False


def _feed(h):
    link.rx.extend(bytes.fromhex(h))


def _tick():
    global stopped
    if stopped:
        return ""
    try:
        fw.step()
    except BreakIn:
        stopped = True
        return "BREAK"
    if not link.tx:
        return ""  # (b"".hex() is b"" on MicroPython, not "")
    out = bytes(link.tx).hex()
    link.tx = bytearray()
    return out


def _due_us():
    due = rt.next_deadline_us()
    return -1 if due is None else max(0, due - rt.clock())


def reboot():
    # The board restarts: its firmware is built again from the board file, on the same
    # filesystem (a configuration saved there is applied) and the same simulated devices.
    global fw, rt
    fw = Firmware(BOARD, machine, link)
    rt = fw.runtime


def _ctl(src):
    env = {"WORLD": WORLD, "fw": fw, "rt": rt, "machine": machine, "reboot": reboot, "result": None}
    exec(src, env)
    return repr(env["result"])


def _ident():
    import sys

    version = ".".join(str(v) for v in sys.implementation.version[:3])
    return "%s %s" % (sys.implementation.name, version)
