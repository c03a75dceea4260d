# The board's log (docs/board-log.md): lines with a level, each driver's faults said once and
# then counted, a budget of lines a second; the lines reach the host in a SIF of their own.
#
# Theory of operation
# -------------------
# line(level, text, source, kind) makes one log SIF (cmd LOG_CMD, with the board's SIF seq like
# every other SIF) when `level` is at least the log's own (INFO: DEBUG lines are not made unless
# asked for) and the budget allows:
#
#     [Q board µs][B level][B source][B kind][H dropped][text: UTF-8, at most TEXT_MAX bytes]
#
# level as rcl_interfaces/msg/Log has it (DEBUG 10, INFO 20, WARN 30, ERROR 40); source the id
# of the transducer the line is about (SOURCE_BOARD: the board itself); kind the fault's kind
# (LINE: not a fault); dropped the lines the budget held back since the line before, so a host
# can count every one.  The budget is a leaky bucket (GCRA on the board clock, integers only):
# BURST lines at once, then one every INTERVAL_US.  A line over it is dropped and counted; a
# count that no line has carried yet goes out on its own (an empty text) as soon as the budget
# has room again (poll: the runtime's loop).
#
# fault(source, kind, text, level): a driver's fault (a device not answering, a bad checksum, a
# bus error, a timeout), or the runtime's (code that raised, storage that failed).  The first of
# a (source, kind) is said; a table of FAULTS entries counts it and every repeat, which are never
# said again.  A fault that finds the table full is counted in `other`, unsaid.  a2jLogInfo tells
# the counts (a host reads it when it connects, and now and then: it shows them, and says the
# faults that happened before it was there):
#
#     [I lines said][I lines dropped][I faults beyond the table][B n]
#     + n * [B source][B kind][I count]
#
# A board without Part 2 (the 2014 firmware's function table) makes no log SIF: its hosts know
# none.  The same format, budget and table on AVR (firmware/avr/src/log.c).
#
# MicroPython subset only.

import struct

LOG_CMD = 0xFE  # the SIF cmd: not a transducer id (0..239), not an error code (0xF0..0xF4)
DEBUG = 10
INFO = 20
WARN = 30
ERROR = 40
SOURCE_BOARD = 0xFF

# fault kinds (the host names them: host/board_log.py)
LINE = 0
NO_ANSWER = 1  # no acknowledge, no echo: absent, unpowered, not wired
WRONG_ID = 2  # an identity register holds another part's value
BUS = 3  # the bus failed during a transfer
TIMEOUT = 4  # a measurement that did not end in time
CHECKSUM = 5
OVERRUN = 6  # data lost before it was read: a buffer overflowed, edges came too fast
RAISED_CALL = 7  # a J2A function raised
RAISED_POLL = 8  # a driver raised in its poll
RAISED_TIMED = 9  # a timed call raised (timing.py)
RAISED_SAFE = 10  # making an actuator safe raised (failsafe.py)
STORAGE = 11  # the configuration's storage failed (config.py)
BAD_REPLY = 12  # a function answered what J2A cannot carry
ECHOED = 13  # a request whose opcode is an error code (0xF0..0xF4): an error frame heard back

HEAD = "<QBBBH"
HEAD_LEN = 13
TEXT_MAX = 255 - HEAD_LEN
BURST = 8
INTERVAL_US = 250000  # 4 lines a second after the burst
FAULTS = 16


def encode_line(stamp_us, level, source, kind, dropped, text):
    data = text.encode()[:TEXT_MAX]
    return struct.pack(HEAD, stamp_us, level, source, kind, min(dropped, 0xFFFF)) + data


class BoardLog:
    def __init__(self, clock, send=None):
        self.clock = clock
        self.send = send  # send(payload): queue one log SIF (None: a board that makes none)
        self.level = INFO
        self.said = 0  # lines sent since boot
        self.dropped = 0  # lines the budget held back since boot
        self.other = 0  # faults that found the table full
        self._pending = 0  # dropped lines no line has carried yet
        self._tat = 0  # the budget's theoretical arrival time (board µs)
        self._faults = []  # [source, kind, count], in the order they were first seen

    def _room(self, now):
        if now < self._tat - (BURST - 1) * INTERVAL_US:
            return False
        self._tat = (self._tat if self._tat > now else now) + INTERVAL_US
        return True

    def line(self, level, text, source=SOURCE_BOARD, kind=LINE):
        if level < self.level or self.send is None:
            return
        now = self.clock()
        if not self._room(now):
            self.dropped += 1
            self._pending += 1
            return
        self._emit(now, level, source, kind, text)

    def _emit(self, now, level, source, kind, text):
        carried = min(self._pending, 0xFFFF)
        self.send(encode_line(now, level, source & 0xFF, kind, carried, text))
        self._pending -= carried
        self.said += 1

    def fault(self, source, kind, text, level=WARN):
        for f in self._faults:
            if f[0] == source and f[1] == kind:
                f[2] += 1
                return
        if len(self._faults) >= FAULTS:
            self.other += 1
            return
        self._faults.append([source, kind, 1])
        self.line(level, text, source, kind)

    def count(self, source, kind):
        for f in self._faults:
            if f[0] == source and f[1] == kind:
                return f[2]
        return 0

    def poll(self, now):
        # a count of dropped lines that no line carried: on its own, once the budget has room
        if self._pending and self.send is not None and self._room(now):
            self._emit(now, WARN, SOURCE_BOARD, LINE, "")

    def next_due_us(self):
        # when poll() has a count to send (None: nothing waits)
        if not self._pending or self.send is None:
            return None
        return self._tat - (BURST - 1) * INTERVAL_US

    def info(self, payload):
        # a2jLogInfo (a reply holds 40 entries; FAULTS is less)
        out = struct.pack(
            "<IIIB",
            self.said & 0xFFFFFFFF,
            self.dropped & 0xFFFFFFFF,
            self.other & 0xFFFFFFFF,
            len(self._faults),
        )
        for source, kind, n in self._faults:
            out += struct.pack("<BBI", source, kind, min(n, 0xFFFFFFFF))
        return 0, out


class SourceLog:
    # What a driver is handed (driver.log, set by the runtime): its own transducer's lines.
    def __init__(self, log, source):
        self.log = log
        self.source = source

    def line(self, level, text):
        self.log.line(level, text, self.source)

    def fault(self, kind, text, level=WARN):
        self.log.fault(self.source, kind, text, level)


def report(driver, kind, text, level=WARN):
    # A driver's fault, said once and then counted (a driver outside a runtime says nothing).
    log = getattr(driver, "log", None)
    if log is not None:
        log.fault(kind, text, level)


class WrongPart(OSError):
    # an identity register that names another part (a driver raises it where it starts one)
    pass


class NoReady(OSError):
    # a part that answers but never says it is ready (a calibration that does not end)
    pass


def bus_fault(driver, e, starting):
    # A transfer on the driver's bus failed: another part than it drives, a part that never got
    # ready, one that does not answer while it is started (absent, unpowered, not wired), or the
    # bus failing later on.  Said once per kind, then counted.
    at = " at 0x%02x" % driver.address if hasattr(driver, "address") else ""
    if isinstance(e, WrongPart):
        report(driver, WRONG_ID, "%s%s" % (e, at))
    elif isinstance(e, NoReady):
        report(driver, TIMEOUT, "%s%s" % (e, at))
    elif starting:
        report(driver, NO_ANSWER, "not answering%s (%s)" % (at, e))
    else:
        report(driver, BUS, "bus error%s (%s)" % (at, e))
