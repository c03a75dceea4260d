"""Live view in Foxglove: a WebSocket server (foxglove-sdk) with every topic as a ros2msg/CDR
channel, plus ``/diagnostics``.  Open Foxglove, "Open connection", ``ws://127.0.0.1:8765``.

Listens on 127.0.0.1 by default; set ``host`` to share it on a network on purpose.  A client
whose browser page came from another site is refused unless its origin is in ``origins``, and
only the view's read-only operations reach the SDK (foxglove_gate.py).  Messages are logged at
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
from .foxglove_gate import OriginGate
from .rosbase import RosPublisher

log = logging.getLogger(__name__)


class FoxglovePublisher(RosPublisher):
    name = "foxglove"

    def __init__(self, options: dict[str, Any] | None = None) -> None:
        import foxglove

        opts = dict(options or {})
        super().__init__(str(opts.get("distro", "jazzy")))
        self._fg = foxglove
        self.context = foxglove.Context()
        origins = opts.get("origins", [])
        if not isinstance(origins, list) or not all(isinstance(o, str) for o in origins):
            raise ConfigError('[foxglove] origins: a list like ["https://app.foxglove.dev"]')
        # the SDK's server on loopback only; clients reach it through the gate
        self.server = foxglove.start_server(
            name=str(opts.get("name", "missing-link")),
            host="127.0.0.1",
            port=0,
            context=self.context,
        )
        host = str(opts.get("host", "127.0.0.1"))
        try:
            self.gate = OriginGate(
                host, int(opts.get("port", 8765)), int(self.server.port), origins
            )
        except OSError as e:
            self.server.stop()
            raise PublisherError(f"foxglove: cannot listen on {host}: {e}") from None
        self.port = self.gate.port
        self.url = f"ws://{host}:{self.port}"
        self._channels: dict[str, Any] = {}
        self._states: dict[str, Update] = {}  # an actuator's topic -> its latest update
        self.logged = 0
        with self._lock:
            self._channel(DIAG_TOPIC, DIAG_TYPE)
        log.info("foxglove: live view at %s", self.url)

    def _channel(self, name: str, type_name: str) -> Any:
        text, _ = self.typestore.generate_msgdef(type_name, ros_version=2)
        schema = self._fg.Schema(name=type_name, encoding="ros2msg", data=text.encode())
        ch = self._fg.Channel(name, schema=schema, message_encoding="cdr", context=self.context)
        self._channels[name] = ch
        return ch

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
        ch.log(update.cdr, log_time=update.stamp_ns)
        self.logged += 1
        if update.topic.transducer.is_actuator:
            self._states[update.topic.name] = update

    def send_diagnostics(self, cdr: bytes, now_ns: int) -> None:
        self._channels[DIAG_TOPIC].log(cdr, log_time=now_ns)
        for name, update in list(self._states.items()):  # (see the module's docstring)
            self._channels[name].log(update.cdr, log_time=update.stamp_ns)

    def shutdown(self) -> None:
        self.gate.close()
        for ch in self._channels.values():
            ch.close()
        self.server.stop()

    def status(self) -> dict[str, Any]:
        return {
            **super().status(),
            "origins_refused": self.gate.refused_origins,
            "client_messages_dropped": self.gate.dropped_messages,
        }
