# The simulator's side inside MicroPython: the firmware from the board file on a link whose bytes
# the node host moves, with the world's devices created from the same board file.
# _feed(hex) hands received bytes to the link, _tick() runs one firmware step and returns the
# bytes to send (hex), _ctl(src) runs test code against WORLD and returns repr() of `result`
# (reboot() restarts the firmware on the same filesystem and devices).

import machine
import simdevices
from board import BOARD
from machine import WORLD
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
        if dev is not None:
            WORLD.devices[t["name"]] = dev


_populate(BOARD)
wire = SimLink()  # the bytes node moves (signed records on a network board)
link = wire
if BOARD.get("link", {}).get("key_file"):  # a network board: signed records (signing.py)
    from mlboard.clock import default_clock
    from mlboard.link import signed

    _clock = default_clock()
    link = signed(wire, BOARD["link"], lambda: _clock() // 1000)
fw = Firmware(BOARD, machine, link)
rt = fw.runtime
stopped = False


def _feed(h):
    wire.rx.extend(bytes.fromhex(h))


def _tick():
    global stopped
    if stopped:
        return ""
    try:
        fw.step()
    except BreakIn:
        stopped = True
        return "BREAK"
    if not wire.tx:
        return ""  # (b"".hex() is b"" on MicroPython, not "")
    out = bytes(wire.tx).hex()
    wire.tx = bytearray()
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
