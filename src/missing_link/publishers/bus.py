"""``bus``: the in-process publisher.  Applications subscribe by topic name (or ``*`` patterns);
messages published on actuator command topics go to the board.

A slow subscriber must not slow a board: by default each subscription has its own bounded queue
(``queue=10000`` updates) drained by its own thread, in order; when the callback falls that far
behind, the oldest updates are dropped and counted (``Subscription.dropped``, the bus's
``dropped``, ``/diagnostics``).  ``queue=0`` calls the callback inline on the board's reader
thread instead: no thread hop, but a slow callback then delays that board.  A callback that
raises is counted (the subscription's ``errors``; by kind in the bus's ``faults``: its status's
``error_kinds``) and the first of each kind logged with its traceback; it never ends a
thread.

The boards' logs (docs/board-log.md) come here too: ``subscribe_logs`` (``Daemon.subscribe_logs``)
calls back with each :class:`~missing_link.host.board_log.LogLine` of a board (or of the boards a
pattern names), on the same queues."""

from __future__ import annotations

import functools
import re
import threading
from collections import deque
from collections.abc import Callable
from typing import Any

from ..host.board_log import LogLine
from ..ros.logmsgs import log_topic
from ..topics import Topic, Update
from .base import Publisher

Callback = Callable[[Update], None]
LogCallback = Callable[[LogLine], None]
CommandHandler = Callable[[Any], None]


@functools.lru_cache(maxsize=256)
def topic_pattern(pattern: str) -> re.Pattern[str]:
    """``*`` and ``?`` match within one level of a topic name, ``**`` across levels."""
    out = []
    i = 0
    while i < len(pattern):
        c = pattern[i]
        if pattern.startswith("**", i):
            out.append(".*")
            i += 2
            continue
        out.append("[^/]*" if c == "*" else "[^/]" if c == "?" else re.escape(c))
        i += 1
    return re.compile("".join(out) + r"\Z")


class Subscription:
    def __init__(
        self, bus: Bus, pattern: str, callback: Callable[[Any], None], queue: int = 10_000
    ) -> None:
        """``callback`` takes an Update (``subscribe``) or a LogLine (``subscribe_logs``)."""
        self.bus, self.pattern, self.callback = bus, pattern, callback
        self.queue = queue
        self.delivered = 0
        self.dropped = 0
        self.errors = 0
        self._items: deque[Any] = deque()
        self._lock = threading.Lock()
        self._ready = threading.Event()
        self._cancelled = False
        self._thread: threading.Thread | None = None
        if queue > 0:
            self._thread = threading.Thread(target=self._drain, name=f"bus:{pattern}", daemon=True)
            self._thread.start()

    def deliver(self, update: Update | LogLine) -> None:
        """Called by the bus on the thread that reads the board (the daemon's I/O loop)."""
        if self._thread is None:
            self._call(update)
            return
        with self._lock:
            if len(self._items) >= self.queue:
                self._items.popleft()  # the oldest goes: the subscriber sees the newest data
                self.dropped += 1
            self._items.append(update)
        self._ready.set()

    def _drain(self) -> None:
        while not self._cancelled:
            self._ready.wait(0.5)
            self._ready.clear()
            while True:
                with self._lock:
                    if not self._items:
                        break
                    batch = list(self._items)
                    self._items.clear()
                for update in batch:
                    if self._cancelled:
                        return
                    self._call(update)

    def _call(self, update: Update | LogLine) -> None:
        try:
            self.callback(update)
            self.delivered += 1
        except Exception as e:  # noqa: BLE001 - an application's callback must not end the
            self.errors += 1  # board's reading or this thread: counted by kind, said once
            on = update.topic.name if isinstance(update, Update) else log_topic(update.board)
            what = f"subscriber {self.callback!r} on {on}"
            self.bus.faults.caught(f"callback on {self.pattern}", e, what)

    def cancel(self) -> None:
        self.bus._unsubscribe(self)
        self._stop()

    def _stop(self) -> None:
        self._cancelled = True
        self._ready.set()
        t = self._thread
        if t is not None and t is not threading.current_thread():
            t.join(1.0)


class Bus(Publisher):
    name = "bus"
    takes_commands = True  # (in-process: the allow-list still applies, daemon/control/allowlist.py)

    def __init__(self, options: dict[str, Any] | None = None) -> None:
        self._lock = threading.Lock()
        self._exact: dict[str, list[Subscription]] = {}
        self._patterns: list[Subscription] = []
        self._commands: dict[str, CommandHandler] = {}
        self._last: dict[str, Update] = {}
        self.topics: dict[str, Topic] = {}
        self._logs: list[Subscription] = []  # subscribe_logs

    # ---- for applications ---------------------------------------------------------------------
    def subscribe(
        self, topic: str, callback: Callback, *, queue: int = 10_000, latest: bool = False
    ) -> Subscription:
        """Call ``callback(update)`` for every update on ``topic``.  Patterns: ``*`` and ``?``
        match within one level (``/board/*``), ``**`` across levels (``/board/**``).
        ``queue``: updates held for a slow callback before the oldest are dropped (counted);
        0 calls it inline on the thread that reads the board.  ``latest``: first the newest
        update each matching topic already had (an actuator's state, which the board reports
        only when it changes)."""
        if queue < 0:
            raise ValueError(f"queue = {queue}: 0 (inline) or a positive number of updates")
        sub = Subscription(self, topic, callback, queue)
        with self._lock:
            if "*" in topic or "?" in topic:
                self._patterns.append(sub)
                matching = [n for n in self.topics if topic_pattern(topic).match(n)]
                for name in matching:  # topics that already exist match at once
                    self._exact.setdefault(name, []).append(sub)
            else:
                matching = [topic]
                self._exact.setdefault(topic, []).append(sub)
            if latest:
                for name in matching:
                    last = self._last.get(name)
                    if last is not None:
                        sub.deliver(last)
        return sub

    def subscribe_logs(
        self, callback: LogCallback, board: str = "*", *, queue: int = 10_000
    ) -> Subscription:
        """Call ``callback(line)`` for every line of the log of ``board`` (a name, or a pattern
        as ``subscribe`` takes: ``*`` every board), as it arrives (``queue`` as ``subscribe``)."""
        if queue < 0:
            raise ValueError(f"queue = {queue}: 0 (inline) or a positive number of lines")
        sub = Subscription(self, f"/{board}/log", callback, queue)
        with self._lock:
            self._logs.append(sub)
        return sub

    def log(self, line: LogLine) -> None:
        name = log_topic(line.board)
        for sub in list(self._logs):  # (a copy: one may unsubscribe meanwhile)
            if topic_pattern(sub.pattern).match(name):
                sub.deliver(line)

    def last(self, topic: str) -> Update | None:
        return self._last.get(topic)

    def send(self, topic: str, value: Any) -> None:
        """Publish a command, e.g. ``bus.send("/thesis/servo/cmd", 40)``: the board's actuator
        function is called with it (asynchronously; latest command wins)."""
        handler = self._commands.get(topic)
        if handler is None:
            known = ", ".join(sorted(self._commands)) or "none yet"
            raise KeyError(f"no actuator listens on {topic!r} (command topics: {known})")
        handler(value)

    @property
    def command_topics(self) -> list[str]:
        return sorted(self._commands)

    # ---- for the daemon -----------------------------------------------------------------------
    def add_command(self, topic: str, handler: CommandHandler) -> None:
        self._commands[topic] = handler

    def remove_command(self, topic: str) -> None:
        self._commands.pop(topic, None)

    def add_topic(self, topic: Topic) -> None:
        with self._lock:
            self.topics[topic.name] = topic
            for sub in self._patterns:  # pattern subscribers learn the exact name
                if topic_pattern(sub.pattern).match(topic.name):
                    subs = self._exact.setdefault(topic.name, [])
                    if sub not in subs:
                        subs.append(sub)

    def publish(self, update: Update) -> None:
        name = update.topic.name
        self._last[name] = update
        for sub in self._exact.get(name, ()):
            sub.deliver(update)

    def subscriptions(self) -> list[Subscription]:
        with self._lock:
            subs = {id(s): s for lst in self._exact.values() for s in lst}
            subs.update((id(s), s) for s in self._patterns)
            subs.update((id(s), s) for s in self._logs)
        return list(subs.values())

    @property
    def dropped(self) -> int:  # type: ignore[override]
        return sum(s.dropped for s in self.subscriptions())

    @property
    def errors(self) -> int:
        return sum(s.errors for s in self.subscriptions())

    def status(self) -> dict[str, Any]:
        out = super().status()
        subs = self.subscriptions()
        out.update(
            subscriptions=len(subs),
            delivered=sum(s.delivered for s in subs),
            callback_errors=self.errors,
            slowest=max((len(s._items) for s in subs), default=0),
        )
        if self.errors:
            out.update(level=max(out["level"], 1), message=f"{self.errors} callback errors")
        return out

    def close(self) -> None:
        for sub in self.subscriptions():
            sub._stop()

    def _unsubscribe(self, sub: Subscription) -> None:
        with self._lock:
            for subs in self._exact.values():
                if sub in subs:
                    subs.remove(sub)
            if sub in self._patterns:
                self._patterns.remove(sub)
            if sub in self._logs:
                self._logs.remove(sub)
