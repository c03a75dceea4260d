# The firmware of a MicroPython sensor board: a board file in, a running J2A board out.
#
# Theory of operation
# -------------------
# The board file (board.py on the device, `BOARD = {...}`, the same file the host reads for
# `missing-link flash` and `gen-firmware`) names the board, its link, its buses and its
# transducers, each with a driver from mlboard.drivers and that driver's pins and options.
# build() turns it into a BoardRuntime: one Transducer per entry, its descriptor fields from the
# driver's defaults overridden by the entry, actuators registered as J2A functions (refused while
# their transducer is disabled), and the run-time configuration (config.py) with its keys and
# the record saved in `config_file` (default mlconfig.bin), applied at boot.
#
# Firmware.step() is one turn of the board's loop: read what the link has, feed it to the runtime
# (which answers requests at once), let the drivers run (poll), write replies then SIFs.
# Firmware.run() repeats it for ever, sleeping on the link until input or the next driver
# deadline.  The simulator calls step() itself.  Both keep the whole loop under one guard: an
# exception anywhere in it (a turn, a driver's deadline, the link's wait) stops the firmware
# only after it made every armed actuator safe.
#
# The way back to the REPL: the link turns Ctrl-C off (a 0x03 inside a frame is data), and the
# break is a sequence between frames that line noise does not make: "\x03\x03repl" then CR or
# LF (wire.BREAK: Ctrl-C twice, "repl", Enter in a terminal).  Two bytes 0x03 used to be enough,
# and three bytes of noise (aa 03 03) stopped a board with its actuators running.  mpremote's own
# "\r\x03" does not stop the firmware: `missing-link flash` sends the break first
# (docs/hardware.md, "Flashing").  Whatever stops the firmware - the break, or an exception -
# first brings every armed actuator to its safe state and drops the timed calls (failsafe.stop),
# so nothing it drove goes on without it; a crash is said in the log (ERROR) on its way out.
# Within SPIN_US of a timed call (timing.py) the loop does not sleep: the link's wait counts in
# ms, a timed call wants its µs.  A turn ends at the loop's idle point, where the firmware
# collects garbage itself when there is room before the next instant it must be on time for
# (memory.py; MicroPython only: CPython has no heap to keep).

import struct

from .clock import resolution_us
from .config import RuntimeConfig
from .drivers import driver_class
from .failsafe import Failsafe
from .identity import machine_id
from .log import ERROR
from .memory import Memory
from .runtime import BoardRuntime, Transducer
from .store import FileStore
from .timing import Timing

RESERVED = ("name", "id", "driver", "prefix", "model", "dtype", "na", "call", "bus", "options",
            "failsafe_ms")  # fmt: skip
SPIN_US = 2000


class BreakIn(Exception):
    pass


def open_buses(board, machine):
    buses = {}
    for name, cfg in board.get("buses", {}).items():
        cfg = dict(cfg)
        kind = cfg.pop("kind", "i2c")
        if kind != "i2c":
            raise ValueError("bus %s: only i2c buses are supported" % name)
        bus_id = cfg.pop("id", 0)
        if "scl" in cfg:
            cfg["scl"] = machine.Pin(cfg["scl"])
        if "sda" in cfg:
            cfg["sda"] = machine.Pin(cfg["sda"])
        buses[name] = machine.I2C(bus_id, **cfg)
    return buses


def describe(entry, cls):
    # The Transducer a board file entry declares: the driver's defaults, overridden by the entry
    # (shared with the host's AVR generator, so both describe a board file alike).
    options = {}
    for key in cls.OPTIONS:
        options[key] = cls.OPTIONS[key]
    for key in entry.get("options", {}):
        options[key] = entry["options"][key]
    if hasattr(cls, "command"):
        options["kind"] = "actuator"
        options["call"] = entry.get("call", "a2j_set_" + entry["name"])
    if "rate_hz" in entry:
        options["rate_hz"] = entry["rate_hz"]
    return Transducer(
        entry["name"],
        entry["id"],
        entry.get("prefix", cls.PREFIX),
        entry.get("model", cls.MODEL),
        cls.CHANNELS,
        entry.get("dtype", cls.DTYPE),
        entry.get("na", cls.NA),
        **options,
    )


def build(board, machine, clock=None, store=None):
    # -> (runtime, {transducer name: driver}); store: where the configuration is saved
    # (default: the file named by the board file's `config_file`)
    name = board["name"]
    uid = machine_id(machine)  # board.id: the chip's (a port without one: the board file's serial)
    rt = BoardRuntime(
        name,
        board.get("model", "missing-link micropython board"),
        board.get("serial") or uid or "unknown",
        fw_version=board.get("fw_version", "0.2.0"),
        clock=clock,
        board_id=uid or board.get("serial") or "unknown",
    )
    rt.set_property("clock.res_us", str(resolution_us(rt.clock)))
    buses = open_buses(board, machine)
    drivers = {}
    for entry in board["transducers"]:
        cls = driver_class(entry["driver"])
        params = {}
        for key in entry:
            if key not in RESERVED:
                params[key] = entry[key]
        if "bus" in entry:
            if entry["bus"] not in buses:
                raise ValueError("%s: no bus %s in the board file" % (entry["name"], entry["bus"]))
            params["i2c"] = buses[entry["bus"]]
        drv = cls(machine, rt.clock, **params)
        if "failsafe_ms" in entry:
            drv.failsafe_ms = entry["failsafe_ms"]  # (failsafe.py; a run-time key too)
        t = describe(entry, cls)
        if hasattr(drv, "command"):
            rt.add_function(t.options["call"], rt.gated(t, drv.command))
        rt.add_transducer(t, drv)
        drivers[entry["name"]] = drv
    if store is None:
        store = FileStore(board.get("config_file", "mlconfig.bin"))
    rt.timing = Timing(rt)  # aligned sampling, timed calls (before the configuration's keys)
    rt.failsafe = Failsafe(rt)  # actuators made safe when the host is gone (ditto)
    rt.config = RuntimeConfig(rt, store)
    rt.add_function("a2jLogInfo", rt.log.info)  # the log's counts (log.py)
    heap = _heap()  # (memory last: its first collection takes what the build left)
    rt.memory = Memory(rt, heap) if heap is not None else None  # (memory.py: a2jMemory)
    return rt, drivers


def _heap():
    # MicroPython's gc (a heap to keep: memory.py), None on CPython
    import gc

    return gc if hasattr(gc, "mem_free") else None


class Firmware:
    def __init__(self, board, machine, link, clock=None, store=None):
        self.board = board
        self.runtime, self.drivers = build(board, machine, clock, store)
        self.link = link
        if hasattr(link, "stats"):  # a signed link: what it dropped, for the host to see
            self.runtime.add_function("a2jLinkStats", self._link_stats)

    def step(self):
        try:
            self._turn()
        except BaseException as e:  # noqa: BLE001 - made safe, then on its way (re-raised)
            self._stops(e)
            raise

    def _stops(self, e):
        # Whatever stops the loop, nothing it drove goes on: every armed actuator safe (and
        # should that raise too - no memory left - every actuator's make_safe, unsaid).
        why = "the break to the REPL" if isinstance(e, BreakIn) else "%s" % e
        try:
            self.runtime.failsafe.stop("the firmware stops: %s" % why)
        except BaseException:  # noqa: BLE001 - the last resort: safe, whatever it costs
            for t in self.runtime.transducers:
                try:
                    t.driver.make_safe()
                except BaseException:  # noqa: BLE001 - (an actuator without one; the others)
                    pass
        if not isinstance(e, BreakIn):
            self._last_words("%s: %s" % (type(e).__name__, e))

    def _last_words(self, why):
        # A crash: the host hears why (the log, ERROR), if the link still takes it.
        rt = self.runtime
        rt.log.line(ERROR, "the firmware stops: %s" % why)
        try:
            out = rt.take_output()
            if out:
                self.link.write(out)
        except Exception:  # noqa: BLE001 - best effort: the firmware stops all the same
            pass

    def _turn(self):
        rt = self.runtime
        data = self.link.read()
        if data:
            rt.feed(data, rt.clock())  # (a2jClock's t2: as the bytes came)
            if rt.breaks:
                raise BreakIn()
        rt.poll()
        out = rt.take_output()
        if out:
            self.link.write(out)
        if rt.memory is not None:
            rt.memory.poll(rt.clock())

    def _link_stats(self, payload):
        # [I records][I bad tags][I replayed][I junk bytes] (signing.py)
        s = self.link.stats()
        n = [v & 0xFFFFFFFF for v in (s["records"], s["bad_tags"], s["replayed"], s["junk"])]
        return 0, struct.pack("<IIII", n[0], n[1], n[2], n[3])

    def run(self):
        try:
            while True:
                self._turn()
                self._rest()
        except BaseException as e:  # noqa: BLE001 - the whole loop, its waits too: made safe
            self._stops(e)
            raise

    def _rest(self):
        # Sleep on the link until input or the next deadline (none near a timed call).
        rt = self.runtime
        precise = rt.timing.next_precise_us()
        if precise is not None and precise - rt.clock() < SPIN_US:
            return  # a timed call is near: no sleep (the link's wait is in ms)
        due = rt.next_deadline_us()
        if precise is not None and due is not None and precise - SPIN_US < due:
            due = precise - SPIN_US
        wait = 10000 if due is None else due - rt.clock()
        if wait > 0:
            self.link.wait(min(wait, 10000))


def main(board=None):
    # main.py on the device: `from mlboard.firmware import main; main()`
    import machine

    from .link import open_link

    if board is None:
        from board import BOARD as board  # noqa: N811 - the board file on the device
    link = open_link(board.get("link", {"kind": "usb"}), machine)
    try:
        Firmware(board, machine, link).run()
    except BreakIn:
        print("missing-link firmware stopped: REPL")
    finally:
        link.close()  # (Ctrl-C on again: after a crash too)
