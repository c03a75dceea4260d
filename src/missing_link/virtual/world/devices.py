"""The simulated devices at their interfaces, for the firmware's drivers under MicroPython or
CPython (machine.py holds the pins, buses and UARTs they sit on), one module per bus: I2C
(i2c_devices.py), UART (uart_devices.py) and plain pins (pin_devices.py).  Each follows its
datasheet with its own tables and arithmetic, so a driver is checked against the part, not
against itself; what a model leaves out is said in its comment.  Tests reach them through WORLD
(WORLD.i2c[(bus, address)], WORLD.uart_sources[id], WORLD.pulses[pin], WORLD.devices), or by
name here; parts.py puts them where a board file says they are wired.  The MicroPython subset
only.
"""

from .i2c_devices import HMC5883L, MPU6050, QMC5883L, SRF02, VL53L0X
from .pin_devices import HCSR04, BatteryPack, Motor, StepperDriver
from .uart_devices import NMEA_EXAMPLE_UTC, GpsReceiver, civil_date

__all__ = [
    "HCSR04", "HMC5883L", "MPU6050", "NMEA_EXAMPLE_UTC", "QMC5883L", "SRF02", "VL53L0X",
    "BatteryPack", "GpsReceiver", "Motor", "StepperDriver", "civil_date",
]  # fmt: skip
