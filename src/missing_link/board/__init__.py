# missing-link board runtime: a J2A sensor board in plain Python (CPython and MicroPython).
#
# On a microcontroller, copy this folder to the device (e.g. as /lib/mlboard) and:
#     from mlboard.runtime import BoardRuntime, Transducer
# Everything here sticks to the MicroPython subset; the host package never needs to be on a board.
