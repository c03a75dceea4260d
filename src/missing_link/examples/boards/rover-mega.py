# The rover's parts on an Arduino Mega 2560 with our C firmware (missing_link/firmware/avr): a
# GPS on Serial1 with its PPS, two DC motors through PWM/DIR bridges (Pololu DRV8838, Cytron
# MD10C), an HC-SR04, a stepper turning a sensor mast and a servo.  Build and flash with:
#   make -C src/missing_link/firmware/avr BOARD=$PWD/examples/boards/rover-mega.py BUILD=build
#   missing-link flash examples/boards/rover-mega.py --port /dev/ttyACM0
# The fixed pins (docs/hardware.md): the motors' PWM on Timer0's OC0A/OC0B (D13, D4), the GPS
# on RX1/TX1 (D19/D18) and its PPS on INT4 (D2), the servo on OC1A (D11).  The motors, the
# stepper and the servo are made safe when the host has been silent for `failsafe_ms`.
BOARD = {
    "name": "mega_rover",
    "model": "mega-rover",
    "mcu": "atmega2560",
    "link": {"kind": "uart", "baudrate": 115200},
    "transducers": [
        {"name": "gps", "id": 0, "driver": "gps_nmea", "uart": 1, "baud": 9600, "pps_pin": 2},
        {"name": "motor_l", "id": 1, "driver": "hbridge", "pwm_pin": 13, "dir_pin": 22,
         "ramp": 4.0, "failsafe_ms": 300, "call": "a2j_motor_l"},
        {"name": "motor_r", "id": 2, "driver": "hbridge", "pwm_pin": 4, "dir_pin": 23,
         "ramp": 4.0, "failsafe_ms": 300, "call": "a2j_motor_r"},
        {"name": "sonar", "id": 3, "driver": "hcsr04", "trig_pin": 24, "echo_pin": 53,
         "rate_hz": 10},
        {"name": "mast", "id": 4, "driver": "stepper", "step_pin": 26, "dir_pin": 27,
         "enable_pin": 28, "steps_per_rev": 200, "microsteps": 2, "max_speed": 1.0,
         "accel": 2.0, "call": "a2j_mast"},
        {"name": "servo", "id": 5, "driver": "servo", "pin": 11, "safe": "limp",
         "call": "a2j_set_servo"},
    ],
}
