# The board runtime: a J2A board in Python that runs unchanged on CPython and MicroPython.
#
# Theory of operation
# -------------------
# The runtime owns a function table (index = J2A opcode), a property table, the transducers and
# their drivers.  The shell around it (a UART loop on a microcontroller, a socket/pty server for
# virtual boards) does three things in a loop:
#
#     runtime.feed(bytes_received)   # parse requests; each complete request is answered at once
#     runtime.poll()                 # let drivers run; turn their new values into sample SIFs
#     out = runtime.take_output()    # bytes to send: whole replies first, then whole SIFs
#
# Replies and SIFs are kept as whole encoded frames in two queues, so a SIF can never land inside
# a reply.  The reply queue goes first: a host waiting on a call (and a2jClock's t3 stamp) should
# not wait behind a burst of samples.  The SIF queue is bounded; when nobody drains it (no host
# attached) the oldest SIFs are dropped and counted, like a UART with nobody listening.
#
# Drivers follow the thesis rule: driver.set_cb(fn); the driver calls fn(channel, value) when it
# has a new value.  The runtime stamps the value with the board clock at that moment, unless the
# driver passes its own stamp (fn(channel, value, stamp_us): taken in an interrupt or computed
# from the measurement, e.g. half an ultrasonic echo's flight after the ping).  A channel
# that already holds an unsent value flushes the transducer's SIF first, so no value is lost.
# Drivers that need CPU time implement poll(now_us) and next_due_us(); a free-running one's
# measurement waits for room before the instants the board must be on time for (pacing.py).
#
# The board's log (log.py, rt.log) queues its lines with the SIFs, as SIFs of their own (cmd
# LOG_CMD, the same seq).  A driver is handed `driver.log` (its transducer's faults: said once,
# then counted); a function that raises, or answers what J2A cannot carry, is said once at ERROR
# and counted there too, besides a2jDebug's text.
#
# MicroPython subset only: no dataclasses, no typing, no f-strings with '='.

import struct

from .builtins import ERR_INDEX, MANY_CHUNK, MANY_KIND, PLAIN_KIND, install
from .clock import default_clock, new_epoch
from .identity import runtime_hash
from .log import BAD_REPLY, ECHOED, ERROR, LOG_CMD, RAISED_CALL, SOURCE_BOARD, BoardLog, SourceLog
from .pacing import Pacing
from .transducer import Transducer  # noqa: F401 - re-exported: boards import it from here
from .wire import (
    EV_BREAK,
    EV_CHECKSUM,
    EV_CUT,
    EV_ESCAPE,
    EV_REQUEST,
    SOF,
    SOS,
    FrameParser,
    encode_frame,
    encode_frame_head,
    encode_frame_tail,
)

J2A_VERSION = "2"
ERR_TIMEOUT = 0xF2
ERR_CHECKSUM = 0xF3
ERR_ESCAPE = 0xF4
INTERBYTE_TIMEOUT_US = 10000
SIF_QUEUE_LIMIT = 64

# Diagnostic values carried in error frames (spec 1.5: any u16; the original sent line numbers).
DIAG_CUT = 1
DIAG_SILENCE = 2
DIAG_CHECKSUM = 3
DIAG_ESCAPE = 4
DIAG_INDEX = 5
_DAMAGED = {EV_CUT: (ERR_TIMEOUT, DIAG_CUT), EV_CHECKSUM: (ERR_CHECKSUM, DIAG_CHECKSUM),
            EV_ESCAPE: (ERR_ESCAPE, DIAG_ESCAPE)}  # fmt: skip


def read_blob(blob, offset):
    # Serve one chunk of a read-only blob for a2jMany: (ret, is_last, data).
    chunk = blob[offset : offset + MANY_CHUNK]
    return 0, offset + len(chunk) >= len(blob), chunk


class BoardRuntime:
    def __init__(
        self,
        name,
        model,
        serial,
        fw_version="0.1.0",
        clock=None,
        epoch=None,
        builtins=True,
        part2=True,
        board_id=None,
        fw_hash=None,
    ):
        self.clock = clock if clock is not None else default_clock()
        self.parser = FrameParser()
        self.functions = []  # (name, kind, handler)
        self.index = {}
        self.properties = {}
        self.transducers = []
        self.drivers = []
        self._replies = []
        self._sifs = []
        self._sif_seq = 0
        self._sif_total = 0  # SIFs queued since boot: the SIF seq, not wrapped
        self._debug = bytearray()
        self._last_byte_us = 0
        self._blobs = {}  # blob function name -> snapshot taken at offset 0
        self._request_us = 0
        self._clock_op = -1
        self.host_map = None  # (board µs, host ns, host ns per board µs in ppb) from the host
        self.config = None  # the run-time configuration (config.py), when the board has one
        self.timing = None  # acting on host time (timing.py), when the board has it
        self.failsafe = None  # actuators made safe when the host is gone (failsafe.py)
        self.pacing = Pacing(self)  # the drivers' polls, kept off the instants (pacing.py)
        self.last_frame_us = 0  # when the host's last request (an intact frame) came: failsafe
        self.sifs_dropped = 0
        self.sifs_sent = 0
        self.calls = 0
        self.breaks = 0  # the break between frames (wire.py): the shell's to act on (firmware.py)
        # the board's log (log.py): lines and faults as log SIFs; none without Part 2
        self.log = BoardLog(self.clock, self._queue_log if part2 else None)
        install(self, builtins, part2)  # the functions every board has (builtins.py)
        if part2:
            self._clock_op = self.index["a2jClock"]  # (answered here: its t3 as late as possible)
            self.set_property("j2a.version", J2A_VERSION)
        self.set_property("board.name", name)
        self.set_property("board.model", model)
        self.set_property("board.serial", serial)
        if part2:  # who it is and what it runs (identity.py; the 2014 firmware had neither)
            self.set_property("board.id", board_id or serial)
        self.set_property("clock.epoch", epoch if epoch is not None else new_epoch())
        self.set_property("clock.res_us", "1")
        self.set_property("fw.version", fw_version)
        fw_hash = runtime_hash() if fw_hash is None and part2 else fw_hash
        if fw_hash:
            self.set_property("fw.hash", fw_hash)

    # ---- configuration -------------------------------------------------------------------
    def _add(self, name, kind, handler):
        if name in self.index:
            raise ValueError("function %s defined twice" % name)
        if len(self.functions) >= 0xF0:
            raise ValueError("function table full (indices 0xF0..0xFF are error codes)")
        self.index[name] = len(self.functions)
        self.functions.append((name, kind, handler))

    def add_function(self, name, handler):
        # handler(payload: bytes) -> (return code 0..255 except 0xF0..0xF4, reply payload)
        self._add(name, PLAIN_KIND, handler)

    def add_many_function(self, name, handler):
        # handler(is_write, is_last, offset, data) -> (return code, is_last, reply data)
        self._add(name, MANY_KIND, handler)

    def add_blob_function(self, name, make_blob):
        # A read-only many-function over the bytes make_blob() returns (snapshot at offset 0).
        def handler(is_write, is_last, offset, data):
            if is_write:
                return 0xFF, False, b""  # flags byte 00, as the original (spec 1.11)
            if offset == 0 or name not in self._blobs:
                self._blobs[name] = make_blob()
            return read_blob(self._blobs[name], offset)

        self.add_many_function(name, handler)

    def set_property(self, key, value):
        key = str(key)
        if not key or "\0" in key or "\0" in str(value):
            raise ValueError("property keys and values must be non-empty text without NUL")
        self.properties[key] = str(value)

    def add_transducer(self, transducer, driver=None):
        for t in self.transducers:
            if t.tid == transducer.tid:
                raise ValueError("transducer id %d used twice" % transducer.tid)
            if t.name == transducer.name:
                raise ValueError("transducer name %s used twice" % transducer.name)
        self.transducers.append(transducer)
        if driver is not None:
            self.drivers.append(driver)
            transducer.driver = driver
            transducer._poll = getattr(driver, "poll", None)
            transducer._due = getattr(driver, "next_due_us", None)
            try:
                driver.log = SourceLog(self.log, transducer.tid)  # its faults (log.py)
            except AttributeError:  # (a driver that takes no attributes logs nothing)
                pass
            if hasattr(driver, "set_cb"):

                def cb(channel, value, stamp_us=None, _t=transducer):
                    self.record(_t, channel, value, stamp_us)

                driver.set_cb(cb)

    def gated(self, transducer, handler):
        # An actuator's command function that refuses while its transducer is disabled; a
        # command it takes arms the failsafe for it (failsafe.py).
        def call(payload):
            if not transducer.enabled:
                return 0xFF, ("%s is disabled" % transducer.name).encode()
            code, reply = handler(payload)
            if code == 0 and self.failsafe is not None:
                self.failsafe.arm(transducer)
            return code, reply

        return call

    def take_debug(self):
        # a2jDebug's text: what was said since the last read (at most 255 bytes), then none
        text = bytes(self._debug[:255])
        self._debug = bytearray()
        return text

    def sifs_queued(self):
        # SIFs queued since boot: the next SIF's seq, not wrapped (a2jSifCount)
        return self._sif_total

    def debug(self, text):
        self._debug.extend(text.encode())
        if len(self._debug) > 255:
            self._debug = self._debug[-255:]

    # ---- samples -------------------------------------------------------------------------
    def record(self, transducer, channel, value, stamp_us=None):
        # Called by drivers (through set_cb): stamp now, or at stamp_us when the driver took the
        # stamp closer to the measurement (in an interrupt, at an echo); keep until poll().
        if not transducer.enabled:
            return
        now = self.clock() if stamp_us is None else stamp_us
        if not (0 <= channel < transducer.chan_count):
            self.debug("%s: no channel %d;" % (transducer.name, channel))
            return
        if value is None:
            value = transducer.na  # the driver says: no valid measurement
        elif not transducer.legal(value):
            transducer.values_dropped += 1
            value = transducer.na
        if transducer._pending[channel] is not None:
            self._queue_sif(transducer, now)
        transducer._pending[channel] = (now, value)
        transducer._dirty = True

    def next_sif_seq(self):
        # The next SIF's seq, counted as sent since boot (a2jSifCount): for this runtime's own
        # SIFs, and for a shell that frames samples itself (bench/_blaster.py).
        seq = self._sif_seq
        self._sif_seq = (seq + 1) & 0xFF
        self._sif_total += 1
        return seq

    def _queue_sif(self, transducer, now):
        payload = transducer.encode_sif(now)
        frame = encode_frame(SOS, self.next_sif_seq(), transducer.tid, payload)
        if len(self._sifs) >= SIF_QUEUE_LIMIT:
            self._sifs.pop(0)
            self.sifs_dropped += 1
        self._sifs.append(frame)

    def _queue_log(self, payload):
        # a log line (log.py): a SIF like any other, with the same seq and the same queue
        frame = encode_frame(SOS, self.next_sif_seq(), LOG_CMD, payload)
        if len(self._sifs) >= SIF_QUEUE_LIMIT:
            self._sifs.pop(0)
            self.sifs_dropped += 1
        self._sifs.append(frame)

    def poll(self):
        now = self.clock()
        if self.failsafe is not None:
            self.failsafe.poll(now)  # first: a silent host's timed calls are dropped, not run
        if self.timing is not None:
            self.timing.poll(now)  # then timed calls: they are due at a tick
        self.pacing.poll(now)  # the drivers: a free-running one off the instants (pacing.py)
        for t in self.transducers:
            if t._dirty:
                self._queue_sif(t, now)
        self.log.poll(now)  # a count of dropped log lines, when the budget has room
        if self.parser.in_frame() and now - self._last_byte_us > INTERBYTE_TIMEOUT_US:
            ev, self._last_byte_us = self.parser.abort(), now  # (its tail is no break: wire.py)
            if ev is not None and ev[1] is not None:
                self._error(ev[1], ERR_TIMEOUT, DIAG_SILENCE)

    def next_deadline_us(self):
        # Board time by which poll() should run again (None: only on input).
        due = None
        pacing = self.pacing
        waits = pacing.waits  # (while one waits: its instant, pacing.py)
        for tr in self.transducers:
            if tr._due is not None and tr.enabled:
                t = tr._due()
                if waits:
                    t = pacing.due_us(tr.tid, t)
                if t is not None and (due is None or t < due):
                    due = t
        if self.parser.in_frame():
            t = self._last_byte_us + INTERBYTE_TIMEOUT_US
            if due is None or t < due:
                due = t
        if self.timing is not None:
            t = self.timing.next_precise_us()
            if t is not None and (due is None or t < due):
                due = t
        if self.failsafe is not None:
            t = self.failsafe.next_due_us()
            if t is not None and (due is None or t < due):
                due = t
        t = self.log.next_due_us()
        if t is not None and (due is None or t < due):
            due = t
        return due

    def take_output(self):
        if not self._replies and not self._sifs:
            return b""
        replies, sifs = self.take_frames()
        return replies + b"".join(sifs)

    def take_frames(self):
        # (replies as one bytes object, [one bytes object per SIF]): for a shell that must
        # never drop a reply but may drop (and count) SIFs when the host does not read.
        replies = self._replies
        for i in range(len(replies)):
            r = replies[i]
            if isinstance(r, tuple):
                # a2jClock: t3 is stamped here, as the reply is handed to the link; only its 8
                # bytes and the checksum are encoded after the stamp (the rest was, at the call).
                replies[i] = encode_frame_tail(r[0], r[1], struct.pack("<Q", self.clock()))
        sifs = self._sifs
        self.sifs_sent += len(sifs)
        self._replies = []
        self._sifs = []
        return b"".join(replies), sifs

    # ---- requests ------------------------------------------------------------------------
    def feed(self, data, rx_us=None):
        # rx_us: board time the shell saw the data arrive (e.g. as the UART/select woke up);
        # a2jClock's t2 is this, so the earlier the shell stamps, the better.
        if not data:
            return
        self._last_byte_us = self.clock() if rx_us is None else rx_us
        for ev in self.parser.feed(data):
            tag = ev[0]
            if tag == EV_REQUEST:
                if ERR_INDEX <= ev[2] <= ERR_ESCAPE:  # an error frame heard back: not the host
                    self.log.fault(SOURCE_BOARD, ECHOED, "")
                    continue
                if ev[2] < len(self.functions):  # a request of the host's: it is there
                    self.last_frame_us = self._last_byte_us
                self._dispatch(ev[1], ev[2], ev[3])
            elif tag == EV_BREAK:
                self.breaks += 1
            elif ev[1] is not None:  # damaged after its seq: its error frame (spec 1.11)
                code, diag = _DAMAGED[tag]
                self._error(ev[1], code, diag)

    def _error(self, seq, code, diag):
        self._replies.append(encode_frame(SOF, seq, code, bytes(((diag >> 8) & 0xFF, diag & 0xFF))))

    def _reply(self, seq, code, payload):
        self._replies.append(encode_frame(SOF, seq, code & 0xFF, payload))

    def _dispatch(self, seq, opcode, payload):
        # The request's last byte arrived no later than the read that delivered it.
        self._request_us = self._last_byte_us
        self.calls += 1
        if opcode >= len(self.functions):
            self._error(seq, ERR_INDEX, DIAG_INDEX)
            return
        _name, kind, handler = self.functions[opcode]
        if opcode == self._clock_op and not payload:
            t2 = struct.pack("<Q", self._request_us)
            self._replies.append(encode_frame_head(SOF, seq, 0, 16, t2))  # t3: take_frames
            return
        if kind != PLAIN_KIND:
            self._reply(seq, 0xFF, b"")  # many-functions are reached through a2jMany only
            return
        try:
            code, reply = handler(payload)
        except Exception as e:  # noqa: BLE001 - a failing function must not stop the board
            self.debug("%s: %s;" % (_name, e))
            self.fault_raised(RAISED_CALL, _name, e)
            code, reply = 0xFF, b""
        if reply is None:  # a2jMany with a target beyond the table (spec 1.7)
            self._error(seq, ERR_INDEX, DIAG_INDEX)
            return
        if 0xF0 <= code <= 0xF4:
            self.debug("%s returned reserved code %d;" % (_name, code))
            self.log.fault(
                SOURCE_BOARD, BAD_REPLY, "%s returned reserved code %d" % (_name, code), ERROR
            )
            code = 0xFF
        if len(reply) > 255:
            self.debug("%s: reply longer than 255 bytes;" % _name)
            self.log.fault(SOURCE_BOARD, BAD_REPLY, "%s: reply over 255 bytes" % _name, ERROR)
            code, reply = 0xFF, b""
        self._reply(seq, code, reply)

    def fault_raised(self, kind, where, e):
        # code that raised, said once (ERROR) and counted: the board goes on (log.py)
        self.log.fault(SOURCE_BOARD, kind, "%s raised %s: %s" % (where, type(e).__name__, e), ERROR)

    # ---- built-in functions ---------------------------------------------------------------
    def mapping_blob(self):
        return b"".join(name.encode() + b"\0" for name, _k, _h in self.functions)

    def properties_blob(self):
        out = []
        for key in self.properties:
            out.append(key.encode() + b"\0" + self.properties[key].encode() + b"\0")
        return b"".join(out)

    def transds_blob(self):
        lines = ["transds/1"]
        for t in self.transducers:
            lines.append(t.descriptor_line())
        return ("\n".join(lines) + "\n").encode()

    def board_time_at(self, host_ns):
        # Board µs at which the host's map reaches host_ns (None: no map yet).  Integer maths
        # only, so it is exact on boards whose floats are 32 bit.
        if self.host_map is None:
            return None
        b0, h0, ppb = self.host_map
        return b0 + ((host_ns - h0) * 1000000) // (1000000000 + ppb)
