# An Uno with a 2S Li-ion pack on a 10k/3k3 divider at A1 and the thesis rig's Sharp at A0 (the
# two share the ADC), for tests/test_avr_battery.py: the battery driver in the AVR C runtime.
BOARD = {
    "name": "power_uno",
    "model": "uno-power",
    "mcu": "atmega328p",
    "link": {"kind": "uart", "baudrate": 115200},
    "transducers": [
        {
            "name": "battery",
            "id": 0,
            "driver": "battery",
            "pin": 1,
            "r_top": 10000.0,
            "r_bottom": 3300.0,
            "vref": 5.0,
            "cells": 2,
            "chemistry": "li-ion",
            "rate_hz": 5,
            "model": "2S Li-ion",
        },
        {"name": "dist_ir", "id": 1, "driver": "sharp_gp2y0a02", "pin": 0, "rate_hz": 10},
    ],
}
