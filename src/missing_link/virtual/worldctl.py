"""The world's control endpoint: a hand that pushes, turns, places, tilts the robot of a running
virtual board, blocks its rangers or fails its sensors (``missing-link world URL VERB ...``,
cli/world.py), on 127.0.0.1 or a unix socket (mode 0600), never further.

Theory of operation
-------------------
One JSON object per line: a request ``{"verb": V, "args": {...}}`` (V: state, or a kind of
event of the world file: push, turn, bump, place, tilt, block, fail, slip, with that event's
keys), then the answer, then the connection closes.  The answer is ``{"state": {...}}`` (the
world's state when it was asked; a push is applied at the world's next batch of ticks) or
``{"error": TEXT, "kind": "usage"}`` for a push the world refuses (an unknown part, a place in
a wall: one line, as the world file's errors).  Bounded: at most MAX_CLIENTS at once, each on
a thread of its own with REQUEST_S to send a request of at most MAX_REQUEST bytes; nothing a
client sends can end the accepting thread.
"""

from __future__ import annotations

import json
import os
import socket
import threading
from typing import Any, Protocol
from urllib.parse import urlsplit

from ..errors import BadURL, ConfigError, MissingLinkError
from .boardfile import listener

MAX_CLIENTS = 4
REQUEST_S = 2.0
MAX_REQUEST = 4096
LOOPBACK = ("127.0.0.1", "localhost", "::1")
MAX_ANSWER = 1 << 20
#: what a state holds that the CLI prints (cli/world.py), each a number
NUMBERS = ("t_s", "x_m", "y_m", "yaw_deg", "speed_m_s", "turn_dps", "battery_v", "bumps")


class Hand(Protocol):
    def push(self, kind: str, args: dict[str, Any]) -> None: ...
    def state(self) -> dict[str, Any]: ...


def answer(hand: Hand, line: bytes) -> dict[str, Any]:
    """The answer to one request line."""
    try:
        req = json.loads(line)
    except (ValueError, UnicodeDecodeError):
        return {"error": "not a JSON request", "kind": "usage"}
    if not isinstance(req, dict) or not isinstance(req.get("args", {}), dict):
        return {"error": 'expected {"verb": V, "args": {...}}', "kind": "usage"}
    verb = req.get("verb")
    try:
        if verb != "state":
            hand.push(str(verb), req.get("args", {}))
        return {"state": hand.state()}
    except ConfigError as e:
        return {"error": str(e), "kind": "usage"}


class WorldControl:
    """The endpoint for ``hand`` on ``url`` (tcp://127.0.0.1:PORT, 0 for any; unix:///PATH);
    ``url`` is then what a client opens.  BadURL for another host."""

    def __init__(self, hand: Hand, url: str) -> None:
        if url.startswith("tcp://") and urlsplit(url).hostname not in LOOPBACK:
            raise BadURL(f"--world-control {url}: on 127.0.0.1 or a unix socket only")
        self.hand = hand
        self.sock, self.url = listener(url)
        if self.sock.family == socket.AF_UNIX:
            os.chmod(self.sock.getsockname(), 0o600)
        self.slots = threading.BoundedSemaphore(MAX_CLIENTS)
        self.refused = 0
        self._thread = threading.Thread(target=self._accept, name="world-control", daemon=True)
        self._thread.start()

    def _accept(self) -> None:
        while True:
            try:
                conn, _ = self.sock.accept()
            except OSError:
                return  # (closed)
            if not self.slots.acquire(blocking=False):
                self.refused += 1
                conn.close()
                continue
            threading.Thread(target=self._serve, args=(conn,), name="world-control:client",
                             daemon=True).start()  # fmt: skip

    def _serve(self, conn: socket.socket) -> None:
        try:
            conn.settimeout(REQUEST_S)
            data = b""
            while b"\n" not in data and len(data) <= MAX_REQUEST:
                got = conn.recv(MAX_REQUEST + 1 - len(data))
                if not got:
                    break
                data += got
            if len(data) > MAX_REQUEST:
                out = {"error": f"a request is at most {MAX_REQUEST} bytes", "kind": "usage"}
            else:
                out = answer(self.hand, data.split(b"\n", 1)[0])
            conn.sendall(json.dumps(out).encode() + b"\n")
        except OSError:
            pass  # (a client that went away or was too slow)
        except Exception as e:  # noqa: BLE001 - said to the client, the endpoint stays
            try:
                conn.sendall(json.dumps({"error": f"{type(e).__name__}: {e}"}).encode() + b"\n")
            except OSError:
                pass
        finally:
            conn.close()
            self.slots.release()

    def close(self) -> None:
        path = self.sock.getsockname() if self.sock.family == socket.AF_UNIX else None
        self.sock.close()
        if path:
            try:
                os.unlink(path)
            except OSError:
                pass


class WorldUnreachable(MissingLinkError):
    """No world answers at that URL (the board is not running, or has no --world-control)."""


def ask(url: str, verb: str, args: dict[str, Any], timeout: float = 5.0) -> dict[str, Any]:
    """One request to the endpoint at ``url``; its answer."""
    parts = urlsplit(url)
    try:
        if parts.scheme == "tcp" and parts.hostname and parts.port:
            sock = socket.create_connection((parts.hostname, parts.port), timeout=timeout)
        elif parts.scheme == "unix" and parts.path:
            sock = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
            sock.settimeout(timeout)
            sock.connect(parts.path)
        else:
            raise BadURL(f"{url!r}: a world's control is tcp://127.0.0.1:PORT or unix:///PATH")
    except (OSError, ValueError) as e:
        raise WorldUnreachable(f"{url}: no world answers there ({e})") from None
    with sock:
        try:
            sock.sendall(json.dumps({"verb": verb, "args": args}).encode() + b"\n")
            data = b""
            while not data.endswith(b"\n") and len(data) <= MAX_ANSWER:
                got = sock.recv(65536)
                if not got:
                    break
                data += got
        except OSError as e:
            raise WorldUnreachable(f"{url}: the world did not answer ({e})") from None
    try:
        return checked(json.loads(data))
    except (ValueError, TypeError):  # (JSON's, or an answer of another shape: not a world's)
        raise WorldUnreachable(f"{url}: not a world's answer") from None


def checked(out: Any) -> dict[str, Any]:
    """``out`` if it is an answer as :func:`answer` makes them (an error's text, or a state of
    the numbers and part names the CLI prints); ValueError else: whatever listens at a URL
    may answer, and its answer is not to end the CLI in a traceback."""
    if len(json.dumps(out)) > MAX_ANSWER or not isinstance(out, dict):
        raise ValueError("not an answer")
    if "error" in out:
        return {"error": str(out["error"]), "kind": str(out.get("kind", "usage"))}
    state = out.get("state")
    if not isinstance(state, dict):
        raise ValueError("no state")
    for key in NUMBERS:
        if isinstance(state.get(key), bool) or not isinstance(state.get(key), (int, float)):
            raise ValueError(key)
    for key in ("blocked", "failed"):
        names = state.get(key, [])
        if not (isinstance(names, list) and all(isinstance(n, str) for n in names)):
            raise ValueError(key)
    return out
