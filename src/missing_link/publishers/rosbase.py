"""The base of the publishers that speak ROS messages (MCAP, Zenoh, ROS 2, ROS 1, Foxglove): a
rosbags typestore for the configured distro, ``/diagnostics`` as ``DiagnosticArray`` CDR, and a
``close`` that runs its shutdown once, whoever calls it and however often."""

from __future__ import annotations

import threading
from typing import Any

from ..ros.diagnostics import diagnostics_cdr
from ..ros.msgs import typestore_for
from .base import Publisher


class RosPublisher(Publisher):
    def __init__(self, distro: str) -> None:
        self.distro = distro
        self.typestore = typestore_for(distro)
        self._lock = threading.Lock()  # guards _closed and the subclass's tables
        self._closed = False

    @property
    def closed(self) -> bool:
        return self._closed

    def diagnostics(self, status: list[dict[str, Any]], now_ns: int) -> None:
        if not self._closed:
            self.send_diagnostics(diagnostics_cdr(self.typestore, status, now_ns), now_ns)

    def send_diagnostics(self, cdr: bytes, now_ns: int) -> None:
        """Hand the ``/diagnostics`` message (CDR) to this face."""
        raise NotImplementedError

    def close(self) -> None:
        with self._lock:
            if self._closed:
                return
            self._closed = True
        self.shutdown()

    def shutdown(self) -> None:
        """Release everything (called once, by the first ``close``)."""
