"""Live view in Foxglove: a WebSocket server speaking the Foxglove WebSocket protocol
(foxglove_server.py) with every topic as a ros2msg/CDR channel, plus ``/diagnostics``.  Open
Foxglove, "Open connection", ``ws://127.0.0.1:8765``.

Listens on 127.0.0.1 by default; set ``host`` to share it on a network on purpose.  That one
port is the view's only listener: a client whose browser page came from another site is refused
unless its origin is in ``origins``, and clients say nothing but subscribe and unsubscribe
(foxglove_server.py says why the Foxglove SDK's own server is not used).  Messages are logged at
the sample's host time (clock sync), so plots line up across boards.

The WebSocket protocol has no latching: a client that connects after an actuator last moved
would not see its state (the board reports it only when it changes).  So the latest state of
every actuator is sent again with each ``/diagnostics`` round (once a second), at its own log
time: a late client has it within a second.
"""

from __future__ import annotations

import logging
from typing import Any

from ..errors import ConfigError
from ..ros.diagnostics import DIAG_TOPIC, DIAG_TYPE
from ..topics import Topic, Update
from .base import PublisherError
from .foxglove_server import LiveView
from .rosbase import RosPublisher

log = logging.getLogger(__name__)


class FoxglovePublisher(RosPublisher):
    name = "foxglove"

    def __init__(self, options: dict[str, Any] | None = None) -> None:
        opts = dict(options or {})
        super().__init__(str(opts.get("distro", "jazzy")))
        origins = opts.get("origins", [])
        if not isinstance(origins, list) or not all(isinstance(o, str) for o in origins):
            raise ConfigError('[foxglove] origins: a list like ["https://app.foxglove.dev"]')
        host = str(opts.get("host", "127.0.0.1"))
        try:
            self.view = LiveView(
                host,
                int(opts.get("port", 8765)),
                origins,
                str(opts.get("name", "missing-link")),
                faults=self.faults,
            )
        except OSError as e:
            raise PublisherError(f"foxglove: cannot listen on {host}: {e}") from None
        self.port = self.view.port
        self.url = f"ws://{host}:{self.port}"
        self._channels: dict[str, int] = {}
        self._states: dict[str, Update] = {}  # an actuator's topic -> its latest update
        self.logged = 0
        with self._lock:
            self._channel(DIAG_TOPIC, DIAG_TYPE)
        log.info("foxglove: live view at %s", self.url)

    def _channel(self, name: str, type_name: str) -> None:
        text, _ = self.typestore.generate_msgdef(type_name, ros_version=2)
        self._channels[name] = self.view.add_channel(name, type_name, text)

    def add_topic(self, topic: Topic) -> None:
        with self._lock:
            if self._closed or topic.name in self._channels:
                return
            topic.register_type(self.typestore)
            self._channel(topic.name, topic.type_name)

    def publish(self, update: Update) -> None:
        ch = self._channels.get(update.topic.name)
        if ch is None or self._closed:
            return
        self.view.log(ch, update.cdr, update.stamp_ns)
        self.logged += 1
        if update.topic.transducer.is_actuator:
            self._states[update.topic.name] = update

    def send_diagnostics(self, cdr: bytes, now_ns: int) -> None:
        self.view.log(self._channels[DIAG_TOPIC], cdr, now_ns)
        for name, update in list(self._states.items()):  # (see the module's docstring)
            self.view.log(self._channels[name], update.cdr, update.stamp_ns)

    def shutdown(self) -> None:
        self.view.close()

    def status(self) -> dict[str, Any]:
        return {
            **super().status(),
            "dropped": self.view.dropped,
            "clients": self.view.clients,
            "subscriptions": self.view.subscriptions,
            "origins_refused": self.view.refused_origins,
            "clients_refused": self.view.refused_clients,
            "client_messages_dropped": self.view.dropped_messages,
        }
