# The simulator's side inside MicroPython: the firmware from the board file on a link whose bytes
# the node host moves, with the world's devices created from the same board file.
# node's TCP connections are the link's (SimServer: as link.py's TcpServer on a device):
# _open(n), _feed(n, hex), _closed(n) say what happened to connection n; _tick() runs one
# firmware step and returns what to send and close ("n:hex" and "-n", space-separated);
# _ctl(src) runs test code against WORLD and returns repr() of `result` (reboot() restarts the
# firmware on the same filesystem and devices).

import machine
import simdevices
from board import BOARD
from machine import WORLD
from mlboard.firmware import BreakIn, Firmware


class SimServer:
    # the TcpServer interface (link.py) over the connections node moves the bytes of
    def __init__(self):
        self.new = []
        self.rx = {}  # open connection -> bytes received
        self.ended = []  # closed by the client (what they sent is read first)
        self.out = []  # "n:hex" to send, "-n" to close

    def accept(self):
        return self.new.pop(0) if self.new else None

    def recv(self, n):
        data = self.rx.get(n)
        if data is None:
            return b""
        if not data:
            if n in self.ended:
                self.ended.remove(n)
                del self.rx[n]
                return b""
            return None
        self.rx[n] = bytearray()
        return bytes(data)

    def send(self, n, data):
        if n not in self.rx or n in self.ended:
            return False
        self.out.append("%d:%s" % (n, bytes(data).hex()))
        return True

    def drop(self, n):
        if self.rx.pop(n, None) is not None:
            self.out.append("-%d" % n)

    def wait(self, us):
        pass

    def close(self):
        pass


I2C_DEVICES = {
    "srf02": (simdevices.SRF02, 0x70),
    "mpu6050": (simdevices.MPU6050, 0x68),
    "hmc5883l": (simdevices.HMC5883L, 0x1E),
    "qmc5883l": (simdevices.QMC5883L, 0x0D),
    "vl53l0x": (simdevices.VL53L0X, 0x29),
}


def _populate(board):
    # the devices the board file says are wired, at their pins and buses (WORLD.devices by
    # transducer name; I2C devices also at WORLD.i2c[(bus, address)])
    buses = board.get("buses", {})
    for t in board["transducers"]:
        drv = t["driver"]
        dev = None
        if drv == "sharp_gp2y0a02":
            WORLD.sharp[t["pin"]] = 800
        elif drv in I2C_DEVICES:
            cls, address = I2C_DEVICES[drv]
            dev = cls(buses[t["bus"]].get("id", 0), t.get("address", address))
        elif drv == "hcsr04":
            dev = simdevices.HCSR04(t["trig_pin"], t["echo_pin"])
        elif drv == "gps_nmea":
            dev = simdevices.GpsReceiver(t["uart"], t.get("pps_pin"), t.get("baud", 9600))
        elif drv == "stepper":
            dev = simdevices.StepperDriver(t["step_pin"], t["dir_pin"], t.get("enable_pin"))
        elif drv == "hbridge":
            dev = simdevices.Motor(t.get("pwm_pin"), t.get("dir_pin"), t.get("in1"), t.get("in2"))
        elif drv == "battery":
            r = (t.get("r_top", 10000.0), t.get("r_bottom", 3300.0))
            dev = simdevices.BatteryPack(t["pin"], r[0], r[1])
        if dev is not None:
            WORLD.devices[t["name"]] = dev


_populate(BOARD)
wire = SimServer()  # node's connections
if BOARD.get("link", {}).get("key_file"):  # a network board: signed records (signing.py)
    from mlboard.clock import default_clock
    from mlboard.link import network_link

    _clock = default_clock()
    link = network_link(wire, BOARD["link"], lambda: _clock() // 1000)
else:  # one host at a time, the newest (a cable has one)
    from mlboard.link import TcpLink

    link = TcpLink(server=wire)
fw = Firmware(BOARD, machine, link)
rt = fw.runtime
stopped = False


def _open(n):
    wire.new.append(n)
    wire.rx[n] = bytearray()


def _feed(n, h):
    if n in wire.rx:
        wire.rx[n].extend(bytes.fromhex(h))


def _closed(n):
    if n in wire.rx:
        wire.ended.append(n)


def _tick():
    global stopped
    if stopped:
        return ""
    try:
        fw.step()
    except BreakIn:
        stopped = True
        return "BREAK"
    out = " ".join(wire.out)
    wire.out = []
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
    env = {
        "WORLD": WORLD,
        "fw": fw,
        "rt": rt,
        "machine": machine,
        "devices": simdevices,
        "reboot": reboot,
        "result": None,
    }
    exec(src, env)
    return repr(env["result"])


def _ident():
    import sys

    version = ".".join(str(v) for v in sys.implementation.version[:3])
    return "%s %s" % (sys.implementation.name, version)
