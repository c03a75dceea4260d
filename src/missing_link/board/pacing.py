# The drivers' polls (runtime.poll), the free-running measurements kept off the instants the
# board must be on time for (docs/hardware.md, "One loop").
#
# Theory of operation
# -------------------
# The board has one loop, and a driver's poll holds it for as long as its measurement takes: an
# MPU-6050's 14-byte I2C read 1.65 ms of a Pico's time at 100 kHz, an HC-SR04's ranging up to
# 33 ms (its echo wait).  A free-running measurement that starts just before an aligned
# measurement's instant or a timed call's tick makes that one late by what is left of it (the
# thesis rig: aligned ADC reads up to 2.27 ms late behind its free-running 100 Hz IMU).  So the
# rule the heap's work follows (memory.py) holds for a paced driver's measurement too
# (timing.fits): it runs only when timing.instant_kept(now) is further away than the longest
# its poll took lately plus MARGIN_US, else at a later turn.  Paced: a driver that says PACED
# (Periodic: a measurement on a rate, which promises a rate and not an instant) and is not
# aligned now.  An aligned one is what the room is kept for; an actuator's or an event driver's
# poll acts at its own time.
#
# * A measurement put off waits out the instant it was put off for, no longer: once that one is
#   served (the next instant is a later one, none is due now), it runs at the next turn, room
#   or not.  A poll longer than any room the grid leaves (a 30 ms one beside a 10 ms grid) so
#   runs right after an instant - as much room as there is - at most one instant late,
#   and is never starved; it still reaches the next instant (counted in `overlaps`).  Only an
#   instant that is close is waited out (within the poll's longest and MARGIN_US): a far one
#   (a 0.1 Hz aligned driver's, a timed call's 9 s ahead) leaves room, the rule says so.  An
#   instant due already when it is put off (an aligned measurement the loop is late for,
#   polled after it) is served this turn: the one after it is the one waited out (AFTER).
# * That room right after an instant is one measurement's: once another paced poll has run
#   since the instant, one that waited it out has the room that is left, and without it waits
#   out the next instant too, once (then it runs, room or not: never starved).  Two that had
#   waited out the same instant ran back to back into the next one.
# * A driver not yet timed (its first measurement) has no length known: the margin alone is
#   its room (an instant that close is waited out; a far one is not waited for: a driver
#   beside a 0.1 Hz grid measured nothing for up to 10 s).
# * A wait is the measurement's while its driver is polled: one whose due moved (a new rate)
#   is a new one, and a driver off (or aligned) has none left, so one enabled again has its
#   room looked at (a wait left over let it through, as one that had waited an instant out).
# * A measurement put off is late, neither lost nor doubled: Periodic measures once when it runs
#   and reckons its next slot from then (a slot the wait covered whole is skipped).
# * A paced driver not due is not polled (its poll only looks: drivers/__init__.py, Periodic);
#   one due is polled with the clock read after its room (poll(now, True): it does not read it
#   again).  While nothing waits, the loop's sleep (runtime.next_deadline_us) is the drivers'
#   own dues, not asked here (`waits` empty).  The clock it is handed is read after the room
#   was looked at (timing.instant_kept's lookup may take a Pico hundreds of µs): drivers that
#   stamp their sample with it (analog.py, sharp.py) stamp their read, not the lookup's start.
# A poll's length is the board clock around it; `longest` (per transducer id) is the longest
# lately, as the heap's pieces' longest so far, but losing a sixteenth a measurement (DECAY): a
# part's start-up in its first measurement (the VL53L0X's calibration, 69 ms) must not keep its
# reads waiting an instant out for ever.  While one waits, the loop sleeps until the instant
# (due_us), not spinning on a due that went by.
# Counted: `deferred`, measurements put off (once each, however many turns they wait);
# `overlaps`, paced polls whose span reached the instant they were let through before (a planned
# one never should: the margin was too thin; one that waited an instant out may).  The host
# reads the two in a2jAlignInfo (timing.py).
#
# MicroPython subset only.

from .timing import fits

#: the longest poll lately, not since boot: it loses a sixteenth a measurement, so a start-up
#: (the rover's VL53L0X calibrates in its first poll: 69 ms) is forgotten within tens of them
#: while a part's usual length holds it up
DECAY = 16
#: a wait's state: it waits out its instant (then runs, room or not, unless another paced poll
#: has run since the instant: OWED), OWED the next one (then runs, room or not), or AFTER the
#: instant after its one, which was due when it was put off (then WAITS for that one)
OWED, WAITS, AFTER = 2, 1, 0


class Pacing:
    def __init__(self, runtime):
        self.rt = runtime
        self.deferred = 0
        self.overlaps = 0
        self.longest = {}  # transducer id -> its longest measuring poll lately (board µs, DECAY)
        # transducer id -> (the instant it waits out, its measurement's due, OWED, WAITS or AFTER)
        self.waits = {}
        self._used = None  # when the last paced poll ended (board µs): the room it took

    def poll(self, now):
        # Every enabled driver's poll, in the transducers' order; a paced one only when due,
        # and then only when there is room for it (or it has waited an instant out).
        rt = self.rt
        timing = rt.timing
        waits = self.waits
        instant = False  # (not looked for yet: once per turn, again after a measurement)
        for t in rt.transducers:
            poll = t._poll
            if poll is None:
                continue
            if not t.enabled:
                if waits and t.tid in waits:
                    del waits[t.tid]  # (off: its wait is over)
                continue
            drv = t.driver
            if timing is None or not getattr(drv, "PACED", False) or drv.aligned:
                if waits and t.tid in waits:
                    del waits[t.tid]  # (aligned now: not paced)
                poll(now)
                continue
            due = t._due()
            if due is not None and now < due:
                continue  # (not due: its poll would only look)
            t0 = rt.clock()
            if instant is False:
                instant = timing.instant_kept(t0)
            if instant is not None and not self._room(t.tid, instant, t0, due):
                continue
            # (read again: the lookup's grid maths and the room's take board time, and the
            # poll stamps its sample with the time it is handed)
            t0 = rt.clock()
            poll(t0, True)  # (the clock just read: Periodic does not read it again)
            t1 = self._used = rt.clock()
            took = self.longest.get(t.tid, 0)
            self.longest[t.tid] = max(t1 - t0, took - took // DECAY)
            if instant is not None and t1 >= instant:
                self.overlaps += 1
            instant = False

    def due_us(self, tid, due):
        # When the driver of transducer `tid` wants its poll (runtime.next_deadline_us, only
        # while any waits): its own due, or, while it waits an instant out, that instant (the
        # loop sleeps until then, not spinning on a due that has gone by).
        waits = self.waits.get(tid)
        if waits is None or waits[1] != due or (due is not None and due > waits[0]):
            return due
        return waits[0]

    def _room(self, tid, instant, now, due):
        # Whether the measurement due at `due` may run now, before `instant`; counts one put
        # off.  A wait is the measurement's: one whose due moved meanwhile (a new rate, the
        # driver off and on) is a new one, not one that has waited an instant out.
        waits = self.waits.get(tid)
        if waits is not None and waits[1] != due:
            waits = None
        if fits(instant, now, self.longest.get(tid, 0)):  # (not timed yet: the margin alone)
            if tid in self.waits:
                del self.waits[tid]
            return True
        if waits is None:
            # (an instant due now is served this turn: the one after it is the one waited out)
            self.waits[tid] = (instant, due, AFTER if instant <= now else WAITS)
            self.deferred += 1
            return False
        if instant <= waits[0] or instant <= now:
            return False  # the instant it waits out (or another, due now) is not served yet
        if waits[2] == AFTER or (
            waits[2] == WAITS and self._used is not None and self._used > waits[0]
        ):
            self.waits[tid] = (instant, due, waits[2] + 1)  # (the next waited out: see WAITS)
            return False
        del self.waits[tid]
        return True  # right after the instant it waited out: as much room as it will get
