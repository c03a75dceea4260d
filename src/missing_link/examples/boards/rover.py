# A small rover on one Raspberry Pi Pico (RP2040) running MicroPython: a GPS with its PPS, a
# compass, an MPU-6050 IMU, two DC motors through a TB6612/DRV8833-style bridge (IN1/IN2 each)
# with their wheel encoders, an HC-SR04 and a VL53L0X looking ahead, and a stepper turning a
# sensor mast.
# Flash it with:  missing-link flash examples/boards/rover.py --port /dev/ttyACM0
# Wiring: docs/hardware.md (a table per driver).  The motors and the stepper stop when the host
# has been silent for `failsafe_ms` (the motors brake; the stepper stops and lets go).
BOARD = {
    "name": "rover",
    "model": "pico-rover",
    "mcu": "rp2040",
    "link": {"kind": "usb"},
    "buses": {
        "i2c0": {"id": 0, "scl": 5, "sda": 4, "freq": 400000},
    },
    "transducers": [
        {"name": "gps", "id": 0, "driver": "gps_nmea", "uart": 1, "tx": 8, "rx": 9,
         "baud": 9600, "pps_pin": 10},
        {"name": "compass", "id": 1, "driver": "qmc5883l", "bus": "i2c0", "rate_hz": 50},
        {"name": "motor_l", "id": 2, "driver": "hbridge", "in1": 12, "in2": 13, "ramp": 4.0,
         "stop": "brake", "failsafe_ms": 300, "call": "a2j_motor_l"},
        {"name": "motor_r", "id": 3, "driver": "hbridge", "in1": 18, "in2": 19, "ramp": 4.0,
         "stop": "brake", "failsafe_ms": 300, "call": "a2j_motor_r"},
        # the wheels' encoders: 1440 counts (edges, x4) per wheel turn, for their JointState
        {"name": "wheel_l", "id": 4, "driver": "quadrature", "pin_a": 2, "pin_b": 3,
         "rate_hz": 50, "options": {"counts_per_rev": 1440}},
        {"name": "wheel_r", "id": 5, "driver": "quadrature", "pin_a": 6, "pin_b": 7,
         "rate_hz": 50, "options": {"counts_per_rev": 1440}},
        {"name": "sonar", "id": 6, "driver": "hcsr04", "trig_pin": 14, "echo_pin": 15,
         "rate_hz": 10},
        {"name": "tof", "id": 7, "driver": "vl53l0x", "bus": "i2c0", "rate_hz": 10},
        {"name": "mast", "id": 8, "driver": "stepper", "step_pin": 20, "dir_pin": 21,
         "enable_pin": 22, "steps_per_rev": 200, "microsteps": 8, "max_speed": 1.0,
         "accel": 2.0, "call": "a2j_mast"},
        {"name": "imu", "id": 9, "driver": "mpu6050", "bus": "i2c0", "rate_hz": 50},
    ],
}
