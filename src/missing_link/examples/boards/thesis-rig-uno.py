# The thesis's test rig on an Arduino Uno (ATmega328P) with our C firmware
# (missing_link/firmware/avr): encoder, Sharp IR ranger, SRF02 sonar, the servo it steers and
# a trigger output (a camera's).
# Build and flash with:
#   make -C src/missing_link/firmware/avr BOARD=$PWD/examples/boards/thesis-rig-uno.py BUILD=build
#   missing-link flash examples/boards/thesis-rig-uno.py --port /dev/ttyACM0
# On AVR the encoder sits on INT0/INT1 (Uno D2/D3), the servo on OC1A (D9), the SRF02 on the
# TWI pins (A4/A5), the Sharp on an ADC channel (pin = 0..7 for A0..A7), the trigger on D11
# (OC2A: Timer2's compare makes its edges, on the tick a host time maps to, docs/timesync.md).
BOARD = {
    "name": "uno_rig",
    "model": "uno-thesis-rig",
    "mcu": "atmega328p",
    "link": {"kind": "uart", "baudrate": 115200},
    "buses": {"twi": {"id": 0}},
    "transducers": [
        # a HEDS-5500 of 500 lines, x4: its angle in rad on /uno_rig/wheel/joint_states
        {"name": "wheel", "id": 0, "driver": "quadrature", "pin_a": 2, "pin_b": 3, "rate_hz": 50,
         "options": {"counts_per_rev": 2000}},
        {"name": "dist_ir", "id": 1, "driver": "sharp_gp2y0a02", "pin": 0, "rate_hz": 25},
        {"name": "sonar", "id": 2, "driver": "srf02", "bus": "twi", "address": 0x70,
         "rate_hz": 10},
        {"name": "servo", "id": 3, "driver": "servo", "pin": 9, "call": "a2j_set_servo"},
        {"name": "camera", "id": 4, "driver": "trigger", "pin": 11, "pulse_us": 20,
         "call": "a2j_trigger"},
    ],
}
