# An ESP32 on WiFi (MicroPython) that dials its daemon, as a micro-ROS client dials its agent:
# the daemon needs no address for the board, and knows it by its board.id (its chip's
# machine.unique_id() in hex), never by the address it comes from (docs/hardware.md, "Boards
# that dial in").  The board joins the network in its boot.py; the firmware then connects to
# the daemon, and again with backoff whenever the connection ends.  Off loopback the daemon
# listens signed, with the key the board has (docs/signing.md):
#   missing-link key new robot.key
#   missing-link flash examples/boards/esp32-dial.py --port /dev/ttyUSB0 --key robot.key
#   missing-link run --listen "signed+tcp://0.0.0.0:7000?key=robot.key" --config robot.toml
# with, in robot.toml, the name it publishes under whatever its address:
#   [boards.arm]
#   id = "<its board.id: missing-link info, or the daemon's status>"
BOARD = {
    "name": "arm",
    "model": "esp32-dial",
    "mcu": "esp32",
    "link": {"kind": "tcp", "dial": "192.168.1.10:7000", "key_file": "mlkey.bin"},
    "transducers": [
        {"name": "dist_ir", "id": 0, "driver": "sharp_gp2y0a02", "pin": 34, "rate_hz": 10},
        {"name": "servo", "id": 1, "driver": "servo", "pin": 13, "call": "a2j_set_servo"},
    ],
}
