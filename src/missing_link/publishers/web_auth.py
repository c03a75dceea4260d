"""The web console's logins (docs/security.md, docs/web.md): the token, taken at ``/login`` only,
and session secrets bound to the origin that logged in.

Theory of operation
-------------------
Cookies do not isolate ports: the session cookie of a console on 127.0.0.1:8080 went with every
request to any other 127.0.0.1 port, whose server then opened the console's WebSocket with it (as
a script does: no ``Origin``) and moved a servo (issue 43.2).  So the console sets no cookie.

* ``/login`` takes the token in ``Authorization: Bearer`` (never in a URL), checked in constant
  time; failures are counted per client address, and after ``LOGIN_FAILURES`` in
  ``LOGIN_WINDOW_S`` that address's logins are refused (429) until its window ends - nobody
  else's (front_door.py's ``LoginLimiter``).  A request without a token is no guess and is not
  counted: a page of another origin in the owner's browser (an image, a link: no header, no
  ``Origin``) would otherwise lock the owner's own address out.  A login answers a fresh
  session secret in its body, bound to the page's origin the login came from (its ``Origin``,
  or the console's own where the browser says ``Sec-Fetch-Site: same-origin``); a login by a
  script binds none.
* The page keeps the secret in ``sessionStorage`` - its own origin's, port included: a page of
  another port cannot read it - and sends it as its WebSocket's first message (``{"op": "auth",
  "session": ...}``).  The console takes it only on a socket whose ``Origin`` is the one the
  secret was made for (one made for none: on any socket the front door admitted,
  front_door.py), within ``AUTH_S`` of the socket opening; otherwise it closes the socket
  (4401) and counts it.
* ``/logout`` (the secret in ``Authorization: Bearer``) ends the session.

Pure: no I/O, time passed in.
"""

from __future__ import annotations

import hmac
import json
import secrets
from dataclasses import dataclass

from .front_door import LoginLimiter

LOGIN_FAILURES, LOGIN_WINDOW_S = 5, 60.0
SESSION_S = 12 * 3600.0
AUTH_S = 5.0  #: s a socket has to send its session (its first message) when a token is set
MAX_SESSIONS = 1024  #: sessions held at once (the oldest go first)
CLOSE_UNAUTHENTICATED = 4401  #: the WebSocket close code of a socket without a session


@dataclass(frozen=True)
class Session:
    expiry: float  #: monotonic s
    origin: str | None  #: the Origin the login came with (None: a script's)


class Logins:
    """The console's token and sessions (``token`` "": no login needed)."""

    def __init__(self, token: str) -> None:
        self.token = token
        self.limiter = LoginLimiter(LOGIN_FAILURES, LOGIN_WINDOW_S)
        self._sessions: dict[str, Session] = {}
        self.refused = 0  #: logins refused (wrong token, or held off)
        self.sockets_refused = 0  #: sockets closed for want of a session

    def login(
        self, authorization: str, client: str, origin: str | None, now: float
    ) -> tuple[int, bytes]:
        """(HTTP status, body) for a ``/login``; 200 carries ``{"session": SECRET}``."""
        if not self.token:
            return 200, b'{"session": ""}'
        if not self.limiter.allows(client, now):
            self.refused += 1
            return 429, b"Too many failed logins: wait a minute\n"
        given = authorization[7:].strip() if authorization.startswith("Bearer ") else ""
        if not given:  # (no guess: a page of another origin can make one without a header,
            return 401, b"Send the token as Authorization: Bearer\n"  # never count it)
        if not hmac.compare_digest(given.encode(), self.token.encode()):
            self.limiter.failed(client, now)
            self.refused += 1
            return 401, b"Wrong token\n"
        sid = secrets.token_urlsafe(32)
        live = {s: x for s, x in self._sessions.items() if x.expiry > now}
        self._sessions = dict(list(live.items())[-(MAX_SESSIONS - 1) :])
        self._sessions[sid] = Session(now + SESSION_S, _origin(origin))
        return 200, json.dumps({"session": sid}).encode()

    def logout(self, authorization: str) -> None:
        if authorization.startswith("Bearer "):
            self._sessions.pop(authorization[7:].strip(), None)

    def admits(self, first: object, origin: str | None, now: float) -> bool:
        """Whether a socket from ``origin`` whose first message is ``first`` is a session's
        (always, where no token is set)."""
        if not self.token:
            return True
        sid = _session_of(first)
        found = self._sessions.get(sid) if sid else None
        ok = found is not None and found.expiry > now and found.origin in (None, _origin(origin))
        if not ok:
            self.sockets_refused += 1
        return ok


def _origin(origin: str | None) -> str | None:
    return origin.rstrip("/") if origin else None


def _session_of(first: object) -> str:
    """The secret of an ``{"op": "auth", "session": ...}`` message, else ""."""
    if not isinstance(first, str) or len(first) > 512:
        return ""
    try:
        m = json.loads(first)
    except (ValueError, RecursionError):
        return ""
    if not isinstance(m, dict) or m.get("op") != "auth" or not isinstance(m.get("session"), str):
        return ""
    return str(m["session"])
