"""The simulator's main.py: a board that starts from its flash (host.mjs --flash DIR holding a
main.py, as `missing-link flash` leaves it), as main.py does on a device.  The MicroPython
subset only.

load() is main.py's start: the root's mlboard/boot.py (what flash put in lib/) chooses the slot
(an update's, or the root's), and that slot's board file and runtime are imported, anything of
an earlier start forgotten.  mpyhost.py builds the firmware from them on the simulator's link,
and attach()es the updater (board/update.py); a restart (after an update's switch, a trial not
confirmed in time, machine.reset(), a firmware on trial that raised: crashed()) loads again from
the flash, as a board that restarts runs main.py again.  main.py itself is not run: its loop
blocks, and the simulator steps the firmware instead.
"""

import sys

ROOT = "/flash"  # the board's filesystem (host.mjs)
adjust = ""  # host.mjs: code run after each start's `import board` (--dial, --no-dial)
chosen = None  # what boot.select() chose at this start
loader = None  # the root's mlboard.boot
updater = None  # the running firmware's (attach)


def _forget():
    for name in list(sys.modules):
        if name == "board" or name == "mlboard" or name.startswith("mlboard."):
            del sys.modules[name]


def load():
    # -> (BOARD, mlboard) of the slot this start runs
    global chosen, loader
    _forget()
    if ROOT + "/lib" not in sys.path:
        sys.path.append(ROOT + "/lib")  # (where main.py finds the root's mlboard)
    # (the board's own modules, on its flash: found by name, as main.py finds them)
    __import__("mlboard.boot")
    loader = sys.modules["mlboard.boot"]
    chosen = loader.select()
    loader.enter(chosen, ROOT)
    for name in ("board", "mlboard.clock", "mlboard.dial", "mlboard.firmware", "mlboard.link",
                 "mlboard.update"):  # fmt: skip
        __import__(name)
    if adjust:
        exec(adjust, {})
    return sys.modules["board"].BOARD, sys.modules["mlboard"]


def attach(rt, board):
    # the running firmware takes updates
    global updater
    updater = sys.modules["mlboard.update"].attach(rt, board, chosen)


def crashed(e):
    # the firmware raised: True when it was on trial (the board restarts and goes back)
    return loader.crashed(chosen, e)


def slot():
    return chosen.slot if chosen is not None else ""
