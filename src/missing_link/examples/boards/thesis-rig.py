# The thesis's test rig on one Raspberry Pi Pico (RP2040) running MicroPython: a wheel encoder,
# a Sharp IR ranger, an SRF02 sonar, the servo it steers, a bumper, an IMU and a trigger output
# (a camera's trigger input: pulses at a host time, docs/timesync.md).
# Flash it with:  missing-link flash examples/boards/thesis-rig.py --port /dev/ttyACM0
# Wiring: docs/hardware.md.  Every key of a transducer that is not a descriptor field
# (name, id, driver, prefix, model, dtype, na, call, bus, options) is the driver's own option.
BOARD = {
    "name": "rig",
    "model": "pico-thesis-rig",
    "mcu": "rp2040",
    "link": {"kind": "usb"},
    "buses": {
        "i2c0": {"id": 0, "scl": 5, "sda": 4, "freq": 100000},
    },
    "transducers": [
        # a HEDS-5500 of 500 lines, x4: its angle in rad on /rig/wheel/joint_states
        {"name": "wheel", "id": 0, "driver": "quadrature", "pin_a": 2, "pin_b": 3, "rate_hz": 50,
         "options": {"counts_per_rev": 2000}},
        {"name": "dist_ir", "id": 1, "driver": "sharp_gp2y0a02", "pin": 26, "rate_hz": 25},
        {"name": "sonar", "id": 2, "driver": "srf02", "bus": "i2c0", "address": 0x70,
         "rate_hz": 10},
        {"name": "servo", "id": 3, "driver": "servo", "pin": 15, "call": "a2j_set_servo"},
        {"name": "bumper", "id": 4, "driver": "digital", "pin": 14, "debounce_ms": 20},
        {"name": "imu", "id": 5, "driver": "mpu6050", "bus": "i2c0", "rate_hz": 100},
        {"name": "camera", "id": 6, "driver": "trigger", "pin": 16, "pulse_us": 100,
         "call": "a2j_trigger"},
    ],
}
