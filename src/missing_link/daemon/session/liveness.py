"""Whether a board's link is alive, decided from what the host hears (pure: time comes in).

Theory of operation
-------------------
The session's supervisor asks a :class:`LinkWatch` what is due, given the time and
``last_frame`` (when the newest intact frame arrived: the board's reading thread stamps it).
Nothing else decides liveness, like a CANopen heartbeat consumer: not what the transport
claims, not whether a call was answered.  The rules, with ``T`` = ``link_timeout``:

* **stale**: no frame for ``T``.  The link is closed, reported and reconnected.  Everything
  else waits for this verdict, never the other way round.
* **heartbeat**: silent for ``T / 2``: make the board answer (a clock probe, or ``a2jEcho``),
  again every ``T / 4`` while the silence lasts, so a quiet but healthy board is heard in time.
* **keepalive**: every ``keep`` s while the board has an armed failsafe (failsafe.py): a frame
  to the board, so that only a host that is gone trips it.
* **ping**: once per diagnostics ``period``: the board's own counts (failsafe trips, alignment)
  and, without clock probes, a round trip.

``wait_s`` says how long the supervisor may sleep until something is due: never past the
instant the link turns stale, so a frozen board is found ``T`` after its last frame plus the
supervisor's wake-up.  That holds only because the supervisor never waits for the board: each
thing it asks is sent and answered in the background, one of a kind at a time (inflight.py),
so a queue of requests ahead of it, a control call with a long timeout or a board that never
answers cannot hold it up.

Silence is evidence only while the host listened: a supervisor that wakes more than ``T / 4``
after the instant it asked for (the host's process was stopped or starved, its reading thread
too, with the board's bytes waiting in the kernel) gives the link ``T / 2`` more before a
verdict, asks the board at once, counts it (``host_stalls``) and says it in its turn
(``host_late``, logged by the session).  Once per silence: a host late again before the board
was heard does not put the verdict off again, so a dead board is found within ``T + T / 2``
plus the wake-ups however late the host keeps running.
"""

from __future__ import annotations

from dataclasses import dataclass

#: the longest the supervisor sleeps: a new failsafe_ms (keepalive) is taken up within it
MAX_SLEEP_S = 1.0


@dataclass(frozen=True)
class Turn:
    """What is due now (at most one verdict: a stale link does nothing else)."""

    stale: bool = False
    silent: float = 0.0  #: s since the last frame
    heartbeat: bool = False
    keepalive: bool = False
    ping: bool = False
    host_late: float = 0.0  #: s the supervisor woke late, when that earned the link a grace


class LinkWatch:
    def __init__(self, link_timeout: float, period: float, now: float) -> None:
        if link_timeout <= 0 or period <= 0:
            raise ValueError("link_timeout and period must be positive")
        self.link_timeout = link_timeout
        self.period = period
        self.next_ping = now  # the first at once (the board's counts in the status)
        self.next_beat = 0.0
        self.next_keep = now
        self.wake_by: float | None = None  # the instant the supervisor asked to wake by
        self.grace_until = 0.0  # no stale verdict before it (the host was not listening)
        self.host_stalls = 0  #: wake-ups later than T / 4: the host, not the board, was silent
        self.graced: float | None = None  # the last frame whose silence had its grace

    def due(self, last_frame: float, keep: float | None) -> float:
        """The next instant something may be due (CLOCK_MONOTONIC s)."""
        t = self.link_timeout
        stale_at = max(last_frame + t, self.grace_until)
        due = min(self.next_ping, max(last_frame + t / 2, self.next_beat), stale_at)
        if keep is not None:
            due = min(due, self.next_keep)
        return due

    def wait_s(self, now: float, last_frame: float, keep: float | None) -> float:
        """How long the supervisor may sleep (commands and a closing link wake it earlier)."""
        wait = max(0.0, min(MAX_SLEEP_S, self.due(last_frame, keep) - now))
        self.wake_by = now + wait
        return wait

    def turn(self, now: float, last_frame: float, keep: float | None) -> Turn:
        """What is due at ``now``; the schedule moves on for what it returns.  (Each instant
        is computed as ``due`` computes it: a wake-up at ``due`` always finds its work.)"""
        t = self.link_timeout
        silent = now - last_frame
        late = 0.0 if self.wake_by is None else now - self.wake_by
        self.wake_by = None
        if late > t / 4:
            self.host_stalls += 1  # (the reading thread was held too: its frames may wait)
            if self.graced != last_frame:  # (one grace per silence)
                self.graced = last_frame
                self.grace_until = now + t / 2
                self.next_beat = 0.0  # ask the board at once
            else:
                late = 0.0
        else:
            late = 0.0
        if now >= max(last_frame + t, self.grace_until):
            return Turn(stale=True, silent=silent)
        keepalive = keep is not None and now >= self.next_keep
        if keepalive:
            assert keep is not None
            self.next_keep = now + keep
        heartbeat = now >= max(last_frame + t / 2, self.next_beat)
        if heartbeat:
            self.next_beat = now + t / 4
        ping = now >= self.next_ping
        if ping:
            self.next_ping = now + self.period
        return Turn(False, silent, heartbeat, keepalive, ping, late)
