"""What the web console shows, kept between the daemon's threads and the console's loop: topics,
the last 30 s of every transducer, each board's configuration, the status.  No I/O; time comes
in as ``now`` (seconds, CLOCK_REALTIME like the samples' host times).

Theory of operation
-------------------
``add_sample`` runs on a board's reading thread for every update: it only appends the update to
its topic's bounded inbox (a full inbox drops the oldest and counts it).  Everything else is the
console loop's: every tick (``drain``) takes what arrived, converts each channel to its SI unit
(web_channels.py: the page shows the part's unit beside it), thins it to at most
``POINTS_PER_TICK`` points per topic (the newest always kept) and keeps a thinner copy, at
most one point per ``HISTORY_STEP_S``, for the last ``WINDOW_S``: a page that opens later is
handed that history (``snapshot``) and the ticks after.
Each topic's rate is what arrived over the last ``RATE_WINDOW_S``.

Configuration: the keys a board offers (``add_config``) with their kind, unit, range and
default; the values after every change (``config_changed``, from any face).  The board says
whether a saved configuration exists and whether the running one differs from it (status
``config_state``), not what the saved values are; so the saved value of a key is known when
nothing differs (it is the running one), ``None`` when nothing is saved (the board boots with
its defaults), and unknown (``"?"``) otherwise, unless this connection saw the running values
while nothing differed.  Nothing shown is guessed.

A board's log (docs/board-log.md): its last ``LOG_LINES`` lines, added to its status as ``log``
(``[{level, text}]``: what the page shows as the board's log).
"""

from __future__ import annotations

import math
import threading
from collections import deque
from collections.abc import Callable
from typing import Any

from ..host.board_log import LogLine
from ..host.config import ConfigKey, Value
from ..topics import Topic, Update
from .web_channels import channels, control, describe

WINDOW_S = 30.0
POINTS_PER_TICK = 50
HISTORY_STEP_S = 0.02
HISTORY_POINTS = int(WINDOW_S / HISTORY_STEP_S) + 10
INBOX = 4096  #: updates of one topic waiting for the next tick
LOG_LINES = 50  #: a board's newest log lines the page shows
RATE_WINDOW_S = 2.0
#: key-name endings that say a configuration key's unit (rate_hz, failsafe_ms, min_us)
UNITS = {"_hz": "Hz", "_ms": "ms", "_us": "µs", "_s": "s", "_deg": "deg", "_mm": "mm", "_cm": "cm"}


def key_unit(name: str) -> str:
    return next((u for end, u in UNITS.items() if name.endswith(end)), "")


def _number(v: Any) -> float | int | None:
    if v is None or isinstance(v, bool):
        return None if v is None else int(v)
    if isinstance(v, int):
        return v
    try:
        f = float(v)
    except (TypeError, ValueError):
        return None
    return f if math.isfinite(f) else None  # (JSON has no NaN: N/A it is)


def thin(points: list[list[Any]], most: int) -> list[list[Any]]:
    """At most ``most`` of ``points``, evenly spread, the first and the newest kept."""
    n = len(points)
    if n <= most:
        return points
    return [points[round(i * (n - 1) / (most - 1))] for i in range(most)]


class _TopicState:
    def __init__(self, topic: Topic, command: str | None, si_command: str | None = None) -> None:
        self.topic = topic
        #: per channel raw -> the SI unit it is shown in (web_channels.py)
        self.convert = [(c.scale, c.offset) for c in channels(topic.transducer)]
        self.command = command  #: its thesis-format command topic (raw values)
        self.si_command = si_command  #: its standard command topic (SI values)
        self.inbox: deque[Update] = deque(maxlen=INBOX)
        self.history: deque[list[Any]] = deque(maxlen=HISTORY_POINTS)
        self.count = 0
        self.dropped = 0
        self.rates: deque[tuple[float, int]] = deque()
        self.last: list[Any] = []

    def meta(self) -> dict[str, Any]:
        t = self.topic.transducer
        return {
            "topic": self.topic.name,
            "board": self.topic.board,
            "name": t.name,
            "model": t.model,
            "unit": t.unit or "",
            "channels": t.chan_count,
            "dtype": t.dtype,
            "kind": t.kind,
            "command": self.command,
            "layout": describe(t),  #: every channel named, its SI and its part's unit
            "control": control(t, self.si_command, self.command),
        }

    def drain(self, now: float) -> list[list[Any]]:
        got: list[list[Any]] = []
        while True:
            try:
                u = self.inbox.popleft()
            except IndexError:
                break
            values = [self._value(v, ch) for ch, v in enumerate(u.values)]
            got.append([u.stamp_ns / 1e9, *values])
        if got:
            self.last = got[-1]
        for p in got:
            if not self.history or p[0] - self.history[-1][0] >= HISTORY_STEP_S:
                self.history.append(p)
        while self.history and self.history[0][0] < now - WINDOW_S:
            self.history.popleft()
        self.rates.append((now, self.count))
        while len(self.rates) > 1 and self.rates[0][0] < now - RATE_WINDOW_S:
            self.rates.popleft()
        return thin(got, POINTS_PER_TICK)

    def _value(self, v: Any, ch: int) -> float | int | None:
        n = _number(v)
        if n is None or ch >= len(self.convert):
            return n
        scale, offset = self.convert[ch]
        return n if (scale, offset) == (1.0, 0.0) else _number(n * scale + offset)

    def rate(self) -> float | None:
        if len(self.rates) < 2:
            return None
        (t0, c0), (t1, c1) = self.rates[0], self.rates[-1]
        return round((c1 - c0) / (t1 - t0), 2) if t1 > t0 else None


class _BoardConfig:
    def __init__(self, keys: list[ConfigKey], values: dict[str, Value]) -> None:
        self.keys = keys
        self.values = dict(values)
        self.flags: set[str] = set()
        self.saved: dict[str, Value] | None = None  #: known saved values (see the docstring)
        self.known = False  #: ``saved`` is known (None then: nothing saved)

    def observe(self, flags: set[str]) -> None:
        self.flags = flags
        if "saved" not in flags:
            self.saved, self.known = None, True
        elif "changed" not in flags:
            self.saved, self.known = dict(self.values), True
        # (saved, and differing: the last known saved values stay, if this link saw them)

    def view(self) -> dict[str, Any]:
        keys = []
        for k in self.keys:
            saved: Any = "?"
            if self.known:
                saved = None if self.saved is None else self.saved.get(k.name)
            keys.append(
                {"key": k.name, "kind": k.kind, "unit": key_unit(k.name), "lo": k.lo,
                 "hi": k.hi, "choices": list(k.choices), "allowed": k.allowed(),
                 "default": k.default, "read_only": k.read_only,
                 "value": self.values.get(k.name), "saved": saved}
            )  # fmt: skip
        return {"keys": keys, "state": sorted(self.flags)}


class ConsoleModel:
    def __init__(self) -> None:
        self._topics: dict[str, _TopicState] = {}
        self._commands: dict[str, Callable[[Any], None]] = {}  # command topic -> deliver
        self._config: dict[str, _BoardConfig] = {}
        self._boards: list[dict[str, Any]] = []
        self._publishers: list[dict[str, Any]] = []
        self._new_topics: list[str] = []
        self._config_dirty: set[str] = set()
        self._logs: dict[str, deque[dict[str, str]]] = {}  # board -> its newest log lines
        self._lock = threading.Lock()

    # ---- the daemon's threads ------------------------------------------------------------------
    def add_topic(self, topic: Topic) -> None:
        if topic.standard:
            return  # (a standard ROS type's mirror of a transducer's topic: shown once, as it)
        with self._lock:
            old = self._topics.get(topic.name)
            state = _TopicState(topic, *((old.command, old.si_command) if old else (None, None)))
            if old is not None:
                state.history, state.count = old.history, old.count
            self._topics[topic.name] = state
            self._new_topics.append(topic.name)

    def add_sample(self, update: Update) -> None:
        st = self._topics.get(update.topic.name)
        if st is None:
            return
        if len(st.inbox) == INBOX:
            st.dropped += 1
        st.inbox.append(update)
        st.count += 1

    def add_command(self, name: str, topic: Topic, deliver: Callable[[Any], None]) -> None:
        """A command topic: the thesis-format one of a transducer's (raw), or its standard one
        (``/<board>/<name>/command``, SI: the page's controls use it where there is one)."""
        with self._lock:
            self._commands[name] = deliver
            if topic.standard:  # (its transducer's topic, found by board and name)
                t = topic.transducer
                st = next((s for s in self._topics.values() if s.topic.board == topic.board
                           and s.topic.transducer.name == t.name), None)  # fmt: skip
                if st is not None and st.si_command != name:
                    st.si_command = name
                    self._new_topics.append(st.topic.name)
                return
            st = self._topics.get(topic.name)
            if st is not None and st.command != name:
                st.command = name
                self._new_topics.append(topic.name)

    def deliver(self, name: str) -> Callable[[Any], None] | None:
        with self._lock:
            return self._commands.get(name)

    def add_config(self, board: str, keys: list[ConfigKey], values: dict[str, Value]) -> None:
        with self._lock:
            self._config[board] = _BoardConfig(keys, values)
            self._config_dirty.add(board)

    def config_changed(self, board: str, values: dict[str, Value]) -> None:
        with self._lock:
            cfg = self._config.get(board)
            if cfg is not None:
                cfg.values.update(values)
                self._config_dirty.add(board)

    def add_log(self, line: LogLine) -> None:
        with self._lock:
            lines = self._logs.setdefault(line.board, deque(maxlen=LOG_LINES))
            lines.append({"level": line.level_name, "text": line.text})

    def set_status(self, boards: list[dict[str, Any]], publishers: list[dict[str, Any]]) -> None:
        """The daemon's status now (``Daemon.status()``, ``publisher_status()``); a board's
        newest log lines go with its status (``log``)."""
        with self._lock:
            logs = self._logs
            boards = [
                {**b, "log": list(logs[str(b.get("board"))])} if str(b.get("board")) in logs else b
                for b in boards
            ]
            self._boards, self._publishers = boards, publishers
        self.observe(boards)

    def observe(self, boards: list[dict[str, Any]]) -> None:
        """What the boards' status says of their saved configuration (``config_state``)."""
        with self._lock:
            for b in boards:
                cfg = self._config.get(str(b.get("board")))
                if cfg is not None and "config_state" in b:
                    flags = {f.strip() for f in str(b["config_state"]).split(",")} - {""}
                    if flags != cfg.flags or not cfg.known:
                        cfg.observe(flags)
                        self._config_dirty.add(str(b["board"]))

    def boards(self) -> list[str]:
        with self._lock:
            return [str(b.get("board")) for b in self._boards]

    # ---- the console's loop ----------------------------------------------------------------
    def snapshot(self) -> dict[str, Any]:
        """Everything a page needs when it opens: topics, their history, configuration, status."""
        with self._lock:
            return {
                "topics": [st.meta() for st in self._topics.values()],
                "history": {n: list(st.history) for n, st in self._topics.items()},
                "config": {b: c.view() for b, c in self._config.items()},
                "boards": self._boards,
                "publishers": self._publishers,
            }

    def drain(self, now: float) -> dict[str, Any]:
        """What arrived since the last tick, for every page."""
        with self._lock:
            topics = list(self._topics.items())
            new = [self._topics[n].meta() for n in dict.fromkeys(self._new_topics)]
            self._new_topics.clear()
            config = {b: self._config[b].view() for b in self._config_dirty}
            self._config_dirty.clear()
            boards, publishers = self._boards, self._publishers
        data: dict[str, Any] = {}
        rates: dict[str, Any] = {}
        for name, st in topics:
            points = st.drain(now)
            if points:
                data[name] = points
            rates[name] = {"rate": st.rate(), "count": st.count, "dropped": st.dropped}
        out: dict[str, Any] = {"op": "tick", "t": now, "data": data, "rates": rates}
        out.update(boards=boards, publishers=publishers)
        if new:
            out["topics"] = new
        if config:
            out["config"] = config
        return out

    def dropped(self) -> int:
        with self._lock:
            return sum(st.dropped for st in self._topics.values())

    def waiting(self) -> int:
        """Updates in the topics' inboxes, not yet taken by a tick."""
        with self._lock:
            return sum(len(st.inbox) for st in self._topics.values())
