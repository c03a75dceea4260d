# main.py of a missing-link MicroPython board: the boot loader.  It runs the firmware in the
# slot the boot record names (mlboard/boot.py): the one `missing-link flash` put in the root, or
# one `missing-link update` put in fw/.  A firmware on trial that raises restarts the board,
# which then goes back to the firmware before it.  flash writes this file; an update never does.
# To get the REPL back, send the break between frames: Ctrl-C twice, "repl", Enter (firmware.py).
import machine
from mlboard import boot as loader

chosen = loader.select()
loader.enter(chosen)  # (the chosen slot's mlboard and board from here on)
try:
    from mlboard import update

    update.run(chosen, machine)
except Exception as e:  # noqa: BLE001 - a firmware on trial that fails: back, at once
    if not loader.crashed(chosen, e):
        raise
    import sys

    sys.print_exception(e)  # type: ignore[attr-defined] - MicroPython's
    machine.reset()
