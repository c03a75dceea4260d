# The thesis's test rig on an Arduino Mega 2560 with our C firmware (missing_link/firmware/avr):
# encoder, Sharp IR ranger, SRF02 sonar and the servo it steers.  Build and flash with:
#   make -C src/missing_link/firmware/avr BOARD=$PWD/examples/boards/thesis-rig-mega.py BUILD=build
#   missing-link flash examples/boards/thesis-rig-mega.py --port /dev/ttyACM0
# On the Mega the encoder sits on INT4/INT5 (D2/D3: INT0/INT1, D21/D20, are the TWI's SCL/SDA),
# the servo on OC1A (D11), the SRF02 on the TWI (SDA D20, SCL D21), the Sharp on an ADC channel
# (pin = 0..7 for A0..A7).
BOARD = {
    "name": "mega_rig",
    "model": "mega-thesis-rig",
    "mcu": "atmega2560",
    "link": {"kind": "uart", "baudrate": 115200},
    "buses": {"twi": {"id": 0}},
    "transducers": [
        # a HEDS-5500 of 500 lines, x4: its angle in rad on /mega_rig/wheel/joint_states
        {"name": "wheel", "id": 0, "driver": "quadrature", "pin_a": 2, "pin_b": 3, "rate_hz": 50,
         "options": {"counts_per_rev": 2000}},
        {"name": "dist_ir", "id": 1, "driver": "sharp_gp2y0a02", "pin": 0, "rate_hz": 25},
        {"name": "sonar", "id": 2, "driver": "srf02", "bus": "twi", "address": 0x70,
         "rate_hz": 10},
        {"name": "servo", "id": 3, "driver": "servo", "pin": 11, "call": "a2j_set_servo"},
    ],
}
