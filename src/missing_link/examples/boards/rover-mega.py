# The rover on an Arduino Mega 2560 with our C firmware (missing_link/firmware/avr): a
# differential drive (two DC motors through PWM/DIR bridges - Pololu DRV8838, Cytron MD10C -
# each with a quadrature encoder on its wheel), an MPU-6050 IMU, a GPS on Serial1 with its PPS,
# an HC-SR04, a stepper turning a sensor mast, a servo and its battery pack.  Build and flash:
#   make -C src/missing_link/firmware/avr BOARD=$PWD/examples/boards/rover-mega.py BUILD=build
#   missing-link flash examples/boards/rover-mega.py --port /dev/ttyACM0
# or try it in simavr, every part simulated at these pins (the motors turn the wheels):
#   missing-link board --file examples/boards/rover-mega.py --runtime avr --listen tcp://127.0.0.1:5000
#
# Wiring (docs/hardware.md has the Mega's pins and which interrupt each has):
#   motor_l   bridge PWM D13 (Timer0's OC0A), DIR D22      motor_r   PWM D4 (OC0B), DIR D23
#   wheel_l   encoder A A8, B A9 (port K's pin-change interrupt, PCINT16/17; 5 V, pulled up)
#   wheel_r   encoder A A10, B A11 (PCINT18/19): mounted mirrored, so its bridge is inverted and
#             its count reversed: "forward" on both drives the rover forward, both counting up
#   imu       MPU-6050 SDA D20, SCL D21 (the TWI; INT0/INT1 are these pins), AD0 low: 0x68
#   gps       TX -> RX1 D19, RX <- TX1 D18, PPS -> D2 (INT4)
#   sonar     HC-SR04 TRIG D24, ECHO D53 (PB0: PCINT0)
#   mast      stepper driver STEP D26, DIR D27, EN D28 (active low)
#   servo     signal D11 (OC1A)
#   battery   the pack through 10k (top) and 3k3 (bottom) to A0
# The motors, the stepper and the servo are made safe when the host has been silent for
# `failsafe_ms`.  Both wheels' encoders give 400 counts (edges, x4) a turn of the wheel: their
# `counts_per_rev` (in the descriptor: their JointState in radians; the rig's wheels turn so).
BOARD = {
    "name": "mega_rover",
    "model": "mega-rover",
    "mcu": "atmega2560",
    "link": {"kind": "uart", "baudrate": 115200},
    "buses": {"twi": {"id": 0}},
    "transducers": [
        {"name": "gps", "id": 0, "driver": "gps_nmea", "uart": 1, "baud": 9600, "pps_pin": 2},
        {"name": "motor_l", "id": 1, "driver": "hbridge", "pwm_pin": 13, "dir_pin": 22,
         "ramp": 4.0, "failsafe_ms": 300, "call": "a2j_motor_l"},
        {"name": "motor_r", "id": 2, "driver": "hbridge", "pwm_pin": 4, "dir_pin": 23,
         "ramp": 4.0, "invert": True, "failsafe_ms": 300, "call": "a2j_motor_r"},
        {"name": "sonar", "id": 3, "driver": "hcsr04", "trig_pin": 24, "echo_pin": 53,
         "rate_hz": 10},
        {"name": "mast", "id": 4, "driver": "stepper", "step_pin": 26, "dir_pin": 27,
         "enable_pin": 28, "steps_per_rev": 200, "microsteps": 2, "max_speed": 1.0,
         "accel": 2.0, "call": "a2j_mast"},
        {"name": "servo", "id": 5, "driver": "servo", "pin": 11, "safe": "limp",
         "call": "a2j_set_servo"},
        {"name": "wheel_l", "id": 6, "driver": "quadrature", "pin_a": 62, "pin_b": 63,
         "rate_hz": 50, "options": {"counts_per_rev": 400}},
        {"name": "wheel_r", "id": 7, "driver": "quadrature", "pin_a": 64, "pin_b": 65,
         "rate_hz": 50, "reverse": True, "options": {"counts_per_rev": 400}},
        {"name": "imu", "id": 8, "driver": "mpu6050", "bus": "twi", "address": 0x68,
         "rate_hz": 50},
        {"name": "battery", "id": 9, "driver": "battery", "pin": 0, "r_top": 10000.0,
         "r_bottom": 3300.0, "cells": 2, "chemistry": "li-ion", "model": "2S Li-ion"},
    ],
}
