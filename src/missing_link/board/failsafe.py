# The failsafe (docs/hardware.md, "Failsafe"): an actuator that keeps running when the host is
# gone is a hazard.
#
# Theory of operation
# -------------------
# Every actuator whose driver has make_safe() gets a run-time key `failsafe_ms` (config.py; the
# board file's `failsafe_ms`, default 500; 0 = never).  The runtime notes when the last intact
# frame came from the host (a request with a good checksum for a function of its table: damaged
# frames, line noise, the board's own error frames heard back are no sign of a living host).
# An actuator that took a command (runtime.gated arms it) and then
# hears no such frame from the host for its `failsafe_ms` is brought to its safe state by its
# driver - a motor coasts or brakes, a stepper stops and lets go, a servo holds its last pulse
# or goes limp, as its keys say - which reports it as a sample stamped when it happened; a line
# goes to a2jDebug and the log (WARN; a make_safe that raises: ERROR, said once, counted).  Only
# an armed actuator trips: one not commanded since it was last made safe (or since boot) is
# safe already, and a board that waits for its host does not trip at boot.  A host that means
# to go says so: a2jGoodbye makes every armed actuator safe at once; so does the firmware
# itself before it stops (a break to the REPL, a crash: firmware.py).
# The daemon keeps a quiet link talking well within the shortest `failsafe_ms`
# (daemon/session/failsafe.py), so only a host that is gone trips it.
#
# Timed calls (timing.py, a2jAt) are commands not yet carried out: a2jGoodbye drops them all, and
# a host silent for the board's shortest non-zero `failsafe_ms` drops those due after that
# (whether or not an actuator is armed; polled before the timed calls run): nothing the host
# asked for moves after it has gone.  (The same rule on AVR, failsafe.c: it cannot tell which
# actuator a timed call is for, so none of the runtimes does.)
#
# a2jFailsafe -> [I trips since boot][I ms since the last trip; 0xFFFFFFFF: none]

import struct

from .log import ERROR, RAISED_SAFE, WARN

DEFAULT_MS = 500


class Failsafe:
    def __init__(self, runtime):
        self.rt = runtime
        self.trips = 0
        self._last_trip_us = None
        self._armed = []  # actuators commanded since they were last made safe
        runtime.add_function("a2jGoodbye", self._goodbye)
        runtime.add_function("a2jFailsafe", self._info)

    def arm(self, t):
        # t took a command (runtime.gated): guarded from now on
        if t not in self._armed and hasattr(t.driver, "make_safe"):
            self._armed.append(t)

    def poll(self, now):
        last = self.rt.last_frame_us
        silent = "no frame from the host for %d ms" % ((now - last) // 1000)
        for t in list(self._armed):
            ms = getattr(t.driver, "failsafe_ms", DEFAULT_MS)
            if ms and now - last >= ms * 1000:
                self._trip(t, silent)
        timing = self.rt.timing
        if timing is not None and timing.pending():
            ms = self._shortest_ms()
            if ms and now - last >= ms * 1000:
                timing.cancel(silent, last + ms * 1000)  # (those due after it went)

    def _shortest_ms(self):
        # the shortest non-zero failsafe_ms of the board's actuators (0: none has one)
        least = 0
        for t in self.rt.transducers:
            if t.driver is not None and hasattr(t.driver, "make_safe"):
                ms = getattr(t.driver, "failsafe_ms", DEFAULT_MS)
                if ms and (not least or ms < least):
                    least = ms
        return least

    def next_due_us(self):
        # when the next armed actuator would trip, or queued timed calls be dropped (None: none)
        due = None
        last = self.rt.last_frame_us
        for t in self._armed:
            ms = getattr(t.driver, "failsafe_ms", DEFAULT_MS)
            if ms:
                d = last + ms * 1000
                if due is None or d < due:
                    due = d
        timing = self.rt.timing
        if timing is not None and timing.pending():
            ms = self._shortest_ms()
            if ms and (due is None or last + ms * 1000 < due):
                due = last + ms * 1000
        return due

    def _trip(self, t, why):
        self._armed.remove(t)
        self.trips += 1
        self._last_trip_us = self.rt.clock()
        log = self.rt.log
        try:
            t.driver.make_safe()
        except Exception as e:  # noqa: BLE001 - the others must still be made safe
            self.rt.debug("failsafe: %s: %s;" % (t.name, e))
            text = "making it safe raised %s: %s" % (type(e).__name__, e)
            log.fault(t.tid, RAISED_SAFE, text, ERROR)  # said once, counted
            return
        self.rt.debug("failsafe: %s safe (%s);" % (t.name, why))
        log.line(WARN, "made safe (%s)" % why, t.tid)

    def stop(self, why):
        # Nothing the board drives goes on: no timed call left (first: none may run meanwhile)
        # and every armed actuator safe.  a2jGoodbye, and a shell about to stop (firmware.py).
        if self.rt.timing is not None:
            self.rt.timing.cancel(why)
        for t in list(self._armed):
            self._trip(t, why)

    def _goodbye(self, payload):
        self.stop("the host said goodbye")
        return 0, b""

    def _info(self, payload):
        age = 0xFFFFFFFF
        if self._last_trip_us is not None:
            age = max(0, min((self.rt.clock() - self._last_trip_us) // 1000, 0xFFFFFFFE))
        return 0, struct.pack("<II", self.trips & 0xFFFFFFFF, age)
