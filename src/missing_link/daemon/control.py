"""The daemon's local control endpoint: a unix socket (mode 0600, in a directory only its user
can enter) through which ``missing-link info``, ``call`` and ``config`` reach a board the daemon
holds, by board name or URL, instead of fighting it for the port (a serial port is locked
exclusively; a virtual board serves one host).  Nothing of it is on a network.

Theory of operation
-------------------
One JSON object per line: a request, then its answer, then the connection closes.  Requests::

    {"op": "find", "board": B}                   -> {"name", "url", "state"}
    {"op": "info", "board": B}                   -> what Board.describe() says
    {"op": "call", "board": B, "function": F, "payload": HEX, "timeout": S}
                                                 -> {"code", "payload": HEX}
    {"op": "config", "board": B, "set": {K: V}, "save": bool, "reset": bool, "erase": bool}
                                                 -> {"values", "keys", "state"}

An answer that failed is ``{"error": TEXT, "kind": K}`` with K ``usage`` (the caller's input:
a bad key or value), ``refused`` (the board said no: nothing changed), ``unconfigurable``,
``board`` (no such board, not up, the link failed).  Each connection is served on a thread of
its own (at most ``MAX_CLIENTS`` at once; the I/O loop is never used for it); a request is
capped in size and time, and text from it is cleaned before it reaches a log.
"""

from __future__ import annotations

import contextlib
import json
import logging
import os
import socket
import stat
import threading
from collections.abc import Callable
from typing import Any

from ..errors import ConfigError, MissingLinkError
from ..text import safe_text

log = logging.getLogger(__name__)

MAX_REQUEST = 64 * 1024
MAX_CLIENTS = 8
CLIENT_TIMEOUT = 30.0
Handler = Callable[[dict[str, Any]], dict[str, Any]]


def default_control_path() -> str:
    """``$MISSING_LINK_CONTROL``, else ``$XDG_RUNTIME_DIR/missing-link/control.sock``, else
    ``/tmp/missing-link-<uid>/control.sock``."""
    env = os.environ.get("MISSING_LINK_CONTROL")
    if env:
        return env
    run = os.environ.get("XDG_RUNTIME_DIR")
    base = os.path.join(run, "missing-link") if run else f"/tmp/missing-link-{os.getuid()}"
    return os.path.join(base, "control.sock")  # (os.path: a one-off call skips pathlib)


def error_kind(e: BaseException) -> str:
    from ..host.config import ConfigRefused, NotConfigurable  # (not on a one-off call's path)

    if isinstance(e, ConfigRefused):
        return "refused"
    if isinstance(e, NotConfigurable):
        return "unconfigurable"
    if isinstance(e, ConfigError):
        return "usage"
    return "board"


class ControlServer:
    """Serves ``handlers`` (op name -> handler(request) -> answer) on the socket at ``path``."""

    def __init__(self, path: str, handlers: dict[str, Handler]) -> None:
        self.path = path
        self.handlers = handlers
        self.requests = 0
        self.refused = 0  #: requests that were not JSON, too big, or of no known op
        self._slots = threading.BoundedSemaphore(MAX_CLIENTS)
        self._sock = _bind(path)
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._accept, name="control", daemon=True)
        self._thread.start()

    def close(self) -> None:
        if self._stop.is_set():
            return
        self._stop.set()
        with contextlib.suppress(OSError):
            self._sock.shutdown(socket.SHUT_RDWR)
        self._sock.close()
        with contextlib.suppress(OSError):
            os.unlink(self.path)
        self._thread.join(1.0)

    def _accept(self) -> None:
        while not self._stop.is_set():
            try:
                conn, _ = self._sock.accept()
            except OSError:
                return  # closed
            if not self._slots.acquire(blocking=False):
                _send(conn, {"error": "daemon busy: too many control clients", "kind": "board"})
                conn.close()
                continue
            threading.Thread(target=self._serve, args=(conn,), daemon=True).start()

    def _serve(self, conn: socket.socket) -> None:
        try:
            conn.settimeout(CLIENT_TIMEOUT)
            _send(conn, self._answer(_read_line(conn)))
        except OSError:
            pass
        finally:
            conn.close()
            self._slots.release()

    def _answer(self, line: bytes | None) -> dict[str, Any]:
        self.requests += 1
        try:
            request = json.loads(line) if line else None
        except ValueError:
            request = None
        op = request.get("op") if isinstance(request, dict) else None
        handler = self.handlers.get(op) if isinstance(op, str) else None
        if request is None or handler is None:
            self.refused += 1
            known = ", ".join(self.handlers)
            return {"error": f"not a control request (ops: {known})", "kind": "usage"}
        try:
            return handler(request)
        except (MissingLinkError, ConfigError, KeyError, TypeError, ValueError) as e:
            return {"error": safe_text(str(e), 400), "kind": error_kind(e)}
        except Exception as e:  # a bug answers; it does not end the endpoint
            log.exception("control: %s failed", safe_text(str(op), 40))
            return {"error": f"internal error: {type(e).__name__}: {e}", "kind": "board"}


def _bind(path: str) -> socket.socket:
    """A socket only this user can reach: its directory 0700 (created), the socket 0600.  An
    endpoint another daemon answers on is not taken over (MissingLinkError); a stale one is."""
    from pathlib import Path

    p = Path(path)
    p.parent.mkdir(mode=0o700, parents=True, exist_ok=True)
    if p.exists() or p.is_symlink():
        if not stat.S_ISSOCK(os.lstat(p).st_mode):
            raise MissingLinkError(f"control endpoint {path}: exists and is not a socket")
        probe = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
        probe.settimeout(0.5)
        try:
            probe.connect(path)
        except OSError:
            os.unlink(path)  # left by a daemon that died
        else:
            raise MissingLinkError(f"control endpoint {path}: another daemon is running there")
        finally:
            probe.close()
    sock = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
    old = os.umask(0o177)
    try:
        sock.bind(path)
    except OSError as e:
        sock.close()
        raise MissingLinkError(f"control endpoint {path}: {e.strerror or e}") from None
    finally:
        os.umask(old)
    os.chmod(path, 0o600)
    sock.listen(MAX_CLIENTS)
    return sock


def _read_line(conn: socket.socket) -> bytes | None:
    buf = b""
    while b"\n" not in buf:
        chunk = conn.recv(4096)
        if not chunk:
            break
        buf += chunk
        if len(buf) > MAX_REQUEST:
            return None
    return buf.split(b"\n", 1)[0] or None


def _send(conn: socket.socket, answer: dict[str, Any]) -> None:
    with contextlib.suppress(OSError):
        conn.sendall(json.dumps(answer).encode() + b"\n")


def ask(path: str, request: dict[str, Any], timeout: float = CLIENT_TIMEOUT) -> dict[str, Any]:
    """One request to the endpoint at ``path``; OSError when nothing answers there."""
    sock = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
    sock.settimeout(timeout)
    try:
        sock.connect(path)
        sock.sendall(json.dumps(request).encode() + b"\n")
        line = _read_line(sock)
    finally:
        sock.close()
    if line is None:
        raise OSError(f"{path}: no answer")
    answer = json.loads(line)
    if not isinstance(answer, dict):
        raise OSError(f"{path}: not an answer")
    return answer
