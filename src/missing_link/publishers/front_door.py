"""The front door of a face that listens on a TCP port for WebSocket clients (docs/security.md):
who may come in, decided before the WebSocket handshake is answered.  Shared by the Foxglove
view (foxglove_server.py) and the web console (web_server.py).

* **Origin**: a browser says which site a page came from in ``Origin``; it is admitted only
  when it is listed (``origins``) or, for a face that serves its own page (``same_origin``), when
  it is that page's own origin (``http(s)://`` + the request's ``Host``).  Any other page in a
  browser on the robot computer is refused (403): it cannot read the data or move the robot.
  Native clients send no ``Origin`` and are admitted (they are local programs, or hold a token).
* **Host** (``hosts``, optional): the names the face answers to.  A page from another site
  that has its own name resolve to 127.0.0.1 (DNS rebinding) sends its own name in ``Host``,
  and with it its own origin, which would pass a same-origin check: it is refused (421).
* **Clients**: at most ``max_clients`` at once (more: 503).

Every refusal is counted (``refused_origins``, ``refused_hosts``, ``refused_clients``) and
logged through the root log filter (logs.py: cleaned, rate-limited), with the header cleaned.
"""

from __future__ import annotations

import ipaddress
import logging
from collections.abc import Iterable
from typing import Any

from ..text import safe_text

log = logging.getLogger(__name__)


def host_name(host_header: str) -> str:
    """The name in a ``Host`` header, without its port (``[::1]:8080`` -> ``::1``)."""
    h = host_header.strip().lower()
    if h.startswith("["):
        return h[1:].split("]", 1)[0]
    return h.rsplit(":", 1)[0] if h.count(":") == 1 else h


def is_loopback(host: str) -> bool:
    """Whether ``host`` (an address or ``localhost``) is this machine's loopback only."""
    h = host.strip("[]").lower()
    if h == "localhost" or h.endswith(".localhost"):
        return True
    try:
        return ipaddress.ip_address(h).is_loopback
    except ValueError:
        return False


class FrontDoor:
    def __init__(
        self,
        face: str,
        origins: Iterable[str] = (),
        max_clients: int = 32,
        *,
        same_origin: bool = False,
        scheme: str = "http",
        hosts: Iterable[str] | None = None,
        origin_option: str = "origins",
    ) -> None:
        self.face = face
        self.origins = frozenset(o.rstrip("/") for o in origins)
        self.max_clients = max_clients
        self.same_origin = same_origin
        self.scheme = scheme
        #: names the face answers to (None: any); loopback names are always among them
        self.hosts = None if hosts is None else frozenset(h.lower() for h in hosts)
        self.origin_option = origin_option
        self.refused_origins = 0
        self.refused_hosts = 0
        self.refused_clients = 0

    def host_ok(self, host_header: str | None) -> bool:
        if self.hosts is None:
            return True
        if not host_header:
            return False
        name = host_name(host_header)
        return is_loopback(name) or name in self.hosts

    def origin_ok(self, origin: str | None, host_header: str | None) -> bool:
        if origin is None:
            return True
        origin = origin.rstrip("/")
        if origin in self.origins:
            return True
        return self.same_origin and bool(host_header) and origin == f"{self.scheme}://{host_header}"

    def refusal(self, request: Any, clients: int = 0) -> tuple[int, str] | None:
        """Why ``request`` (a websockets ``Request``) may not come in, as (HTTP status, text),
        or None: it may.  Counted and logged when refused."""
        hosts, origins = request.headers.get_all("Host"), request.headers.get_all("Origin")
        if len(hosts) > 1 or len(origins) > 1:
            self.refused_hosts += 1
            log.warning("%s: a request with two Host or Origin headers refused", self.face)
            return 400, "Bad request\n"
        host, origin = (hosts or [None])[0], (origins or [None])[0]
        if not self.host_ok(host):
            self.refused_hosts += 1
            log.warning(
                "%s: a request for host %s refused: not a name this face answers to",
                self.face,
                safe_text(host or "(none)", 100),
            )
            return 421, "Misdirected request\n"
        if not self.origin_ok(origin, host):
            self.refused_origins += 1
            log.warning(
                "%s: a client from %s refused: its Origin is not in [%s] %s",
                self.face,
                safe_text(origin or "", 100),
                self.face,
                self.origin_option,
            )
            return 403, "Origin not allowed\n"
        if clients >= self.max_clients:
            self.refused_clients += 1
            log.warning("%s: a client refused: %d are connected already", self.face, clients)
            return 503, "Too many clients\n"
        return None

    def check(self, connection: Any, request: Any, clients: int) -> Any:
        """For websockets' ``process_request``: a refusal response, or None."""
        why = self.refusal(request, clients)
        return None if why is None else connection.respond(*why)


class LoginLimiter:
    """Failed logins per client address (no I/O; time passed in): after ``failures`` in
    ``window_s`` a client's logins are refused until its window ends, and nobody else's are.
    The table holds at most ``max_clients`` addresses; while it is full of addresses that
    failed within the window, every address not in it shares one more entry (``OVERFLOW``),
    limited the same way.  So a guesser with many addresses (all of 127/8 reaches a loopback
    console) costs bounded memory and gets at most ``(max_clients + 1) * failures`` tries a
    window - evicting its own entries would have given it unlimited ones - and only such a
    flood can hold off an address it does not use."""

    OVERFLOW = "(every other address)"

    def __init__(self, failures: int = 5, window_s: float = 60.0, max_clients: int = 1024) -> None:
        self.failures = failures
        self.window_s = window_s
        self.max_clients = max_clients
        self._failed: dict[str, list[float]] = {}  # address -> its failures' times, oldest first

    def __len__(self) -> int:
        return len(self._failed)

    def allows(self, client: str, now: float) -> bool:
        """Whether ``client`` may try a login now."""
        key = self._key(client, now)
        times = self._failed.get(key)
        if times is None:
            return True
        while times and times[0] <= now - self.window_s:
            times.pop(0)
        if not times:
            del self._failed[key]
            return True
        return len(times) < self.failures

    def failed(self, client: str, now: float) -> None:
        times = self._failed.setdefault(self._key(client, now), [])
        times.append(now)
        del times[: -self.failures]

    def _key(self, client: str, now: float) -> str:
        """``client``'s entry: its own, or the shared one while the table is full."""
        if client in self._failed or len(self._failed) < self.max_clients:
            return client
        for k in [k for k, t in self._failed.items() if not t or t[-1] <= now - self.window_s]:
            del self._failed[k]  # (only when full: those whose window has ended make room)
        room = len(self._failed) - (self.OVERFLOW in self._failed) < self.max_clients
        return client if room else self.OVERFLOW
