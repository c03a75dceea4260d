# ruff: noqa: E402, I001  (MicroPython: the modules are found and swapped in before they are imported)
# The simulator's GPS receiver (uart_devices.GpsReceiver) under simulated time (simtime as `time`,
# as host.mjs --fast puts it): run(gap_ms) makes one, lets 2.5 s pass and reads it, then leaves it
# unread `gap_ms` (off in the world, or its transducer disabled), reads it again and 1 ms later,
# and prints how many seconds it counted meanwhile, or the exception.  Run by simworld.mjs.
import sys

sys.path.append("/lib")
import simworld.simtime as simtime

sys.modules["time"] = simtime
from simworld.uart_devices import GpsReceiver


def run(gap_ms):
    gap = gap_ms * 1000  # (µs: past 2^31 a number from node would come as a float)
    dev = GpsReceiver(1)
    simtime.advance(2500000)
    dev.produce(simtime.now_us())
    base0 = dev._base
    while gap > 0:  # (one step at most 500 s, as the host's sleeps would be)
        step = gap if gap < 500000000 else 500000000
        simtime.advance(step)
        gap -= step
    try:
        dev.produce(simtime.now_us())
        simtime.advance(1000)
        dev.produce(simtime.now_us())
        out = '"=", %d' % (dev._base - base0)
    except Exception as e:  # noqa: BLE001 - what it raised is the answer
        out = '"%s", "%s"' % (type(e).__name__, e)
    print('{"got": [%s]}' % out)
