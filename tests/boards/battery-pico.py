# A Pico with a 2S Li-ion pack on a 10k/3k3 divider at GP26 (ADC0) and a bumper, for
# tests/test_standard*.py: the battery driver's BatteryState and the digital input's Bool.
BOARD = {
    "name": "power",
    "model": "pico-power",
    "mcu": "rp2040",
    "link": {"kind": "usb"},
    "transducers": [
        {
            "name": "battery",
            "id": 0,
            "driver": "battery",
            "pin": 26,
            "r_top": 10000.0,
            "r_bottom": 3300.0,
            "cells": 2,
            "chemistry": "li-ion",
            "rate_hz": 5,
            "model": "2S Li-ion",
        },
        {
            "name": "bumper",
            "id": 1,
            "driver": "digital",
            "pin": 14,
            "debounce_ms": 20,
            "rate_hz": 5,
        },
    ],
}
