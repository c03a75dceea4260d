"""The simulated world a board file's firmware runs in: a `machine` module whose pins, buses,
ADC, PWM and UARTs are simulated at their interfaces (machine.py), the parts from their
datasheets (devices.py), put where a board file says they are wired (parts.py).  The same files
run inside MicroPython under node (host.mjs, mpyhost.py: loaded there as the package
`simworld`) and under CPython (virtual/boardfile.py).  Nothing is imported here: MicroPython
imports this package too.
"""
