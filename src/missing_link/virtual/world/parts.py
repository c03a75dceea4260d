"""The parts a board file says are wired, made into device models (devices.py) at their pins
and buses, for both runtimes of a virtual board (MicroPython: mpyhost.py; CPython:
virtual/boardfile.py).  The MicroPython subset only.

Each transducer entry's driver names the part: a Sharp ranger is a voltage on its ADC pin
(800 mm away), an I2C part a register model at its address, an HC-SR04 a pulse on its echo pin,
a GPS receiver NMEA on its UART, a stepper driver and an H-bridge what their inputs make, a
plain analog input a steady mid-scale voltage.  What has nothing to say back (a servo, a
trigger output, an encoder at rest, a switch not pressed) needs no model: the pins are there.

An absent part (`--absent NAME`) is not made: its I2C address does not acknowledge, its UART
stays silent, its echo pin never rises (the firmware's wait runs out), its ADC pin floats.  An
absent output or switch changes nothing the firmware can see (it does not listen back).
"""

from . import devices
from .machine import VREF, WORLD

I2C_PARTS = {
    "srf02": (devices.SRF02, 0x70),
    "mpu6050": (devices.MPU6050, 0x68),
    "hmc5883l": (devices.HMC5883L, 0x1E),
    "qmc5883l": (devices.QMC5883L, 0x0D),
    "vl53l0x": (devices.VL53L0X, 0x29),
}
ADC_PARTS = ("sharp_gp2y0a02", "analog", "battery")
SHARP_MM = 800


def _device(t, buses):
    drv = t["driver"]
    if drv in I2C_PARTS:
        cls, address = I2C_PARTS[drv]
        return cls(buses[t["bus"]].get("id", 0), t.get("address", address))
    if drv == "hcsr04":
        return devices.HCSR04(t["trig_pin"], t["echo_pin"])
    if drv == "gps_nmea":
        return devices.GpsReceiver(t["uart"], t.get("pps_pin"), t.get("baud", 9600))
    if drv == "stepper":
        return devices.StepperDriver(t["step_pin"], t["dir_pin"], t.get("enable_pin"))
    if drv == "hbridge":
        return devices.Motor(t.get("pwm_pin"), t.get("dir_pin"), t.get("in1"), t.get("in2"))
    if drv == "battery":
        return devices.BatteryPack(t["pin"], t.get("r_top", 10000.0), t.get("r_bottom", 3300.0))
    return None


def populate(board, absent=()):
    # WORLD.devices by transducer name (I2C parts also at WORLD.i2c[(bus, address)])
    buses = board.get("buses", {})
    WORLD.names = [t["name"] for t in board["transducers"]]  # (worldfeed.attach's by number)
    for t in board["transducers"]:
        drv = t["driver"]
        if t["name"] in absent:
            if drv in ADC_PARTS:
                WORLD.float_adc(t["pin"])
            continue
        if drv == "sharp_gp2y0a02":
            WORLD.sharp[t["pin"]] = SHARP_MM
        elif drv == "analog":
            WORLD.volts[t["pin"]] = VREF / 2
        dev = _device(t, buses)
        if dev is not None:
            WORLD.devices[t["name"]] = dev
