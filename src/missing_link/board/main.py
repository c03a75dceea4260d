# main.py of a missing-link MicroPython board: serve J2A over the link the board file names.
# To get the REPL back, send the break between frames: Ctrl-C twice, "repl", Enter (firmware.py).
from mlboard.firmware import main

main()
