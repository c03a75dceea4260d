# main.py of a missing-link MicroPython board: serve J2A over the link the board file names.
# To get the REPL back, send two Ctrl-C between frames (mpremote does that by itself).
from mlboard.firmware import main

main()
