# An MPU-6050 and an SRF02 on an Uno's TWI (tests/test_avr_imu.py): the IMU's 14-byte burst on
# a bus it shares.  SDA A4, SCL A5; the IMU's AD0 low (0x68).
BOARD = {
    "name": "imu_uno",
    "model": "uno-imu",
    "mcu": "atmega328p",
    "link": {"kind": "uart", "baudrate": 115200},
    "buses": {"twi": {"id": 0}},
    "transducers": [
        {"name": "imu", "id": 0, "driver": "mpu6050", "bus": "twi", "address": 0x68, "rate_hz": 50},
        {"name": "sonar", "id": 1, "driver": "srf02", "bus": "twi", "address": 0x70, "rate_hz": 10},
    ],
}
