# An ESP32 on WiFi (MicroPython): J2A over TCP in signed records (docs/signing.md).  The board
# joins the network in its boot.py (MicroPython's network.WLAN: the credentials stay the
# user's); the firmware then serves one host at a time on the port.  Make a key, put it on the
# board over USB (never over the network), and give the host the same file:
#   missing-link key new robot.key
#   missing-link flash examples/boards/esp32-wifi.py --port /dev/ttyUSB0 --key robot.key
#   missing-link run "signed+tcp://ROBOT-IP:5000?key=robot.key"
# A board with a key takes nothing unsigned: unsigned, altered, foreign and replayed records
# are dropped and counted on both sides.
BOARD = {
    "name": "wifi",
    "model": "esp32-wifi",
    "mcu": "esp32",
    "link": {"kind": "tcp", "port": 5000, "key_file": "mlkey.bin"},
    "transducers": [
        {"name": "dist_ir", "id": 0, "driver": "sharp_gp2y0a02", "pin": 34, "rate_hz": 10},
        {"name": "servo", "id": 1, "driver": "servo", "pin": 13, "call": "a2j_set_servo"},
    ],
}
