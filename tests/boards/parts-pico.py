# The drivers examples/boards/rover.py does not use, on a Pico, for tests/test_rover.py: the
# HMC5883L compass, a PWM/DIR H-bridge, a servo that goes limp when the host is gone.
BOARD = {
    "name": "parts",
    "model": "pico-parts",
    "mcu": "rp2040",
    "link": {"kind": "usb"},
    "buses": {"i2c0": {"id": 0, "scl": 5, "sda": 4, "freq": 400000}},
    "transducers": [
        {"name": "compass", "id": 0, "driver": "hmc5883l", "bus": "i2c0", "rate_hz": 20},
        {
            "name": "motor",
            "id": 1,
            "driver": "hbridge",
            "pwm_pin": 6,
            "dir_pin": 7,
            "ramp": 0,
            "failsafe_ms": 200,
            "call": "a2j_motor",
        },
        {
            "name": "servo",
            "id": 2,
            "driver": "servo",
            "pin": 15,
            "safe": "limp",
            "call": "a2j_set_servo",
        },
    ],
}
