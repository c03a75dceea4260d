"""``bus``: the in-process publisher.  Applications subscribe by topic name (or ``*`` patterns);
messages published on actuator command topics go to the board.  Callbacks run on the board's
reader thread: keep them short, hand heavy work to a queue."""

from __future__ import annotations

import functools
import logging
import re
import threading
from collections.abc import Callable
from typing import Any

from ..topics import Topic, Update
from .base import Publisher, register_publisher

log = logging.getLogger(__name__)
Callback = Callable[[Update], None]
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
    def __init__(self, bus: Bus, pattern: str, callback: Callback) -> None:
        self.bus, self.pattern, self.callback = bus, pattern, callback

    def cancel(self) -> None:
        self.bus._unsubscribe(self)


class Bus(Publisher):
    name = "bus"

    def __init__(self, options: dict[str, Any] | None = None) -> None:
        self._lock = threading.Lock()
        self._exact: dict[str, list[Subscription]] = {}
        self._patterns: list[Subscription] = []
        self._commands: dict[str, CommandHandler] = {}
        self._last: dict[str, Update] = {}
        self.topics: dict[str, Topic] = {}
        self.errors = 0

    # ---- for applications ---------------------------------------------------------------------
    def subscribe(self, topic: str, callback: Callback) -> Subscription:
        """Call ``callback(update)`` for every update on ``topic``.  Patterns: ``*`` and ``?``
        match within one level (``/board/*``), ``**`` across levels (``/board/**``)."""
        sub = Subscription(self, topic, callback)
        with self._lock:
            if "*" in topic or "?" in topic:
                self._patterns.append(sub)
                for name in self.topics:  # topics that already exist match at once
                    if topic_pattern(topic).match(name):
                        self._exact.setdefault(name, []).append(sub)
            else:
                self._exact.setdefault(topic, []).append(sub)
        return sub

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
            try:
                sub.callback(update)
            except Exception:
                self.errors += 1
                log.exception("bus subscriber %r on %s failed", sub.callback, name)

    def _unsubscribe(self, sub: Subscription) -> None:
        with self._lock:
            for subs in self._exact.values():
                if sub in subs:
                    subs.remove(sub)
            if sub in self._patterns:
                self._patterns.remove(sub)


register_publisher("bus", Bus)
