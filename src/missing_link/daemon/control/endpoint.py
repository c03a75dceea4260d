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
a bad key or value), ``refused`` (the board, or the daemon's ``[daemon] commands`` list, said
no: nothing changed), ``unconfigurable``, ``board`` (no such board, not up, the link failed).

Ours, and it stays up:

* **ours**: the socket's directory must be a real directory (not a link) owned by this user
  that no one else may write to, and the socket this user's.  The server checks before it
  binds and the client (``ask``) before it connects (``check_endpoint``), so another local user
  who made ``/tmp/missing-link-<uid>`` first can neither answer our clients nor be used by our
  daemon: both refuse with a line that says whose it is and what to do.
* **bounded**: each connection is served on a thread of its own (at most ``MAX_CLIENTS`` at
  once; the I/O loop is never used for it).  A client has ``REQUEST_S`` to send its request
  (whole, not per byte) and ``ANSWER_S`` to take the answer, so idle clients cannot hold the
  slots; a request is capped in size (``MAX_REQUEST``) and nesting (``MAX_DEPTH``), its numbers
  must be finite (no ``NaN``, ``Infinity``, ``1e999``), a call's timeout is checked and clamped
  (``call_timeout``), and text from it is cleaned before it reaches a log.
* **up**: a failed ``accept`` (out of descriptors: EMFILE) is counted and said, and accepting
  goes on after a short pause, so the endpoint recovers once descriptors are free; nothing a
  request holds can end the accepting thread or a handler's.
"""

from __future__ import annotations

import contextlib
import errno
import json
import logging
import math
import os
import socket
import stat
import threading
from collections.abc import Callable
from typing import Any

from ...errors import ConfigError, MissingLinkError
from ...host.clock import SYSTEM_CLOCK
from ...logs import ErrorCounts
from ...text import safe_text
from ..paths import runtime_dir

log = logging.getLogger(__name__)

MAX_REQUEST = 64 * 1024
MAX_ANSWER = 1 << 20  #: what a client reads of an answer (info: descriptors, properties)
MAX_DEPTH = 8  #: nesting of a request's JSON (requests are flat: ``set`` is one level)
MAX_CLIENTS = 8
REQUEST_S = 2.0  #: a client's time to send its whole request
ANSWER_S = 5.0  #: ... and to take the answer
CLIENT_TIMEOUT = 30.0  #: what a client waits for an answer by default
#: a control call's timeout is clamped to this (s), as a board's call timeout is
MAX_CALL_TIMEOUT = 60.0
_ACCEPT_PAUSE = (0.01, 1.0)  #: after a failed accept: first pause, longest pause (s)
Handler = Callable[[dict[str, Any]], dict[str, Any]]
#: a socket's deadlines are the kernel's timeouts, real time whatever clock the daemon runs on
_SOCKET_CLOCK = SYSTEM_CLOCK


class NotOurs(MissingLinkError):
    """A control endpoint (or its directory) that someone else owns or can write to."""


def default_control_path() -> str:
    """``$MISSING_LINK_CONTROL``, else ``control.sock`` in :func:`runtime_dir`."""
    env = os.environ.get("MISSING_LINK_CONTROL")
    if env:
        return env
    return os.path.join(runtime_dir(), "control.sock")  # (os.path: a one-off call skips pathlib)


#: how a control endpoint's directory and its socket are said when they are not ours: a failed
#: lstat's prefix, what it is not, whose it is, and a hint
_DIR = ("its directory: ", "{at} is not a directory", "{at}", ": another user may have made it")
_SOCKET = ("", "exists and is not a socket", "the socket", "")
_FIX = "remove it, or choose another place ([daemon] control, $MISSING_LINK_CONTROL)"


def check_endpoint(path: str, uid: int | None = None) -> None:
    """Raise NotOurs unless the endpoint at ``path`` is ours (``uid``: this process's): its
    directory a real directory (not a link) owned by us that no one else can write to, and the
    socket, when there is one, a socket owned by us.  Nothing there yet is fine."""
    uid = os.getuid() if uid is None else uid
    parent = os.path.dirname(path) or "."  # (os.path: a one-off call skips pathlib)
    d = _ours(path, parent, uid, stat.S_ISDIR, _DIR)
    if d is None:
        return
    if d.st_mode & 0o022:
        raise NotOurs(
            f"control endpoint {path}: others may write to {parent} (mode "
            f"{stat.S_IMODE(d.st_mode):o}); {_FIX}"
        )
    _ours(path, path, uid, stat.S_ISSOCK, _SOCKET)


def _ours(
    path: str, at: str, uid: int, is_kind: Callable[[int], bool], say: tuple[str, str, str, str]
) -> os.stat_result | None:
    """``at``'s lstat (None: nothing there); NotOurs, naming the endpoint ``path``, unless it is
    of its kind and ``uid``'s (``say``: :data:`_DIR` or :data:`_SOCKET`)."""
    unreadable, not_kind, whose, hint = say
    try:
        st = os.lstat(at)
    except FileNotFoundError:
        return None
    except OSError as e:
        raise NotOurs(f"control endpoint {path}: {unreadable}{e.strerror or e}") from None
    if not is_kind(st.st_mode):
        raise NotOurs(f"control endpoint {path}: {not_kind.format(at=at)}; {_FIX}")
    if st.st_uid != uid:
        raise NotOurs(
            f"control endpoint {path}: {whose.format(at=at)} belongs to uid {st.st_uid}, not to "
            f"you (uid {uid}){hint}; {_FIX}"
        )
    return st


def call_timeout(value: object) -> float | None:
    """A control call's timeout: None (the board's), else a finite number of seconds > 0,
    clamped to ``MAX_CALL_TIMEOUT``; ConfigError for anything else."""
    if value is None:
        return None
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise ConfigError(f"timeout {safe_text(repr(value), 40)}: expected a number of seconds")
    try:
        t = float(value)
    except OverflowError:  # (an int of 400 digits: JSON has no limit)
        t = math.inf
    if not math.isfinite(t) or t <= 0:
        raise ConfigError(f"timeout {safe_text(repr(t), 40)}: expected a number of seconds > 0")
    return min(t, MAX_CALL_TIMEOUT)


def error_kind(e: BaseException) -> str:
    from ...host.config import ConfigRefused, NotConfigurable  # (not on a one-off call's path
    from .allowlist import CommandRefused

    if isinstance(e, (ConfigRefused, CommandRefused)):
        return "refused"
    if isinstance(e, NotConfigurable):
        return "unconfigurable"
    if isinstance(e, ConfigError):
        return "usage"
    return "board"


def parse_request(line: bytes | None) -> dict[str, Any] | None:
    """A request object, or None for what is not one (too deep, not JSON, a non-finite
    number, not an object)."""
    if not line or _depth(line) > MAX_DEPTH:
        return None
    try:
        request = json.loads(line, parse_constant=_no_constant, parse_float=_finite)
    except (ValueError, RecursionError):
        return None
    return request if isinstance(request, dict) else None


class ControlServer:
    """Serves ``handlers`` (op name -> handler(request) -> answer) on the socket at ``path``."""

    def __init__(self, path: str, handlers: dict[str, Handler]) -> None:
        self.path = path
        self.handlers = handlers
        self.requests = 0
        self.refused = 0  #: requests that were not JSON, too big or deep, or of no known op
        self.busy = 0  #: connections turned away: every slot taken
        self.accept_errors = 0  #: accepts that failed (out of descriptors: EMFILE, ...)
        #: bugs met serving a request, by kind (its answer says "internal error")
        self.faults = ErrorCounts(log, "control")
        self._slots = threading.BoundedSemaphore(MAX_CLIENTS)
        self._sock = _bind(path)
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._accept, name="control", daemon=True)
        self._thread.start()

    def close(self) -> None:
        if self._stop.is_set():
            return
        self._stop.set()
        with contextlib.suppress(OSError):  # (not connected: the close below ends the accept)
            self._sock.shutdown(socket.SHUT_RDWR)
        self._sock.close()
        with contextlib.suppress(OSError):  # (gone already: someone tidied up)
            os.unlink(self.path)
        self._thread.join(1.0)

    def status(self) -> dict[str, Any]:
        """What ``publisher_status`` shows of the endpoint."""
        return {"requests": self.requests, "refused_requests": self.refused,
                "busy": self.busy, "accept_errors": self.accept_errors,
                **self.faults.to_json()}  # fmt: skip

    def _accept(self) -> None:
        pause = _ACCEPT_PAUSE[0]
        said: set[int] = set()
        while not self._stop.is_set():
            try:
                conn, _ = self._sock.accept()
            except OSError as e:
                if self._stop.is_set() or e.errno == errno.EBADF:
                    return  # closed
                # Out of descriptors (or memory): the connection waits in the backlog; try
                # again after a pause, longer while it lasts.  Said once per kind of failure.
                self.accept_errors += 1
                if e.errno not in said:
                    said.add(e.errno or 0)
                    log.warning("control: accept failed (%s); retrying", e.strerror or e)
                self._stop.wait(pause)
                pause = min(pause * 2, _ACCEPT_PAUSE[1])
                continue
            pause = _ACCEPT_PAUSE[0]
            self._dispatch(conn)

    def _dispatch(self, conn: socket.socket) -> None:
        if not self._slots.acquire(blocking=False):
            self.busy += 1
            self._turn_away(conn, "daemon busy: too many control clients")
            return
        try:
            threading.Thread(target=self._serve, args=(conn,), name="control:client",
                             daemon=True).start()  # fmt: skip
        except RuntimeError:  # (no thread to be had: as busy)
            self._slots.release()
            self.busy += 1
            self._turn_away(conn, "daemon busy: no thread for another control client")

    @staticmethod
    def _turn_away(conn: socket.socket, text: str) -> None:
        conn.settimeout(0.2)  # (a small answer into a fresh socket's buffer: never blocks long)
        _send(conn, {"error": text, "kind": "board"})
        conn.close()

    def _serve(self, conn: socket.socket) -> None:
        try:
            line = _read_line(conn, MAX_REQUEST, _SOCKET_CLOCK.monotonic() + REQUEST_S)
            answer = self._answer(line)
            conn.settimeout(ANSWER_S)
            _send(conn, answer)
        except OSError:
            pass  # (a client that went, or was too slow: its slot is free again)
        except Exception as e:  # noqa: BLE001 - a bug of ours: counted, said once; the
            self.faults.caught("serving a client", e)  # endpoint goes on
        finally:
            conn.close()
            self._slots.release()

    def _answer(self, line: bytes | None) -> dict[str, Any]:
        self.requests += 1
        request = parse_request(line)
        op = request.get("op") if request is not None else None
        handler = self.handlers.get(op) if isinstance(op, str) else None
        if request is None or handler is None:
            self.refused += 1
            known = ", ".join(self.handlers)
            return {"error": f"not a control request (ops: {known})", "kind": "usage"}
        try:
            return handler(request)
        except (MissingLinkError, ConfigError, KeyError, TypeError, ValueError) as e:
            return {"error": safe_text(str(e), 400), "kind": error_kind(e)}
        except Exception as e:  # noqa: BLE001 - a bug answers (and is counted, said once); it
            self.faults.caught(f"op {safe_text(str(op), 20)}", e)  # does not end the endpoint
            return {"error": f"internal error: {type(e).__name__}: {e}", "kind": "board"}


def _no_constant(name: str) -> Any:
    raise ValueError(f"{name} is not a number here")


def _finite(text: str) -> float:
    x = float(text)
    if not math.isfinite(x):
        raise ValueError(f"{text[:20]} is not a finite number")
    return x


def _depth(line: bytes) -> int:
    """How deep ``line``'s JSON nests (brackets outside strings), without parsing it."""
    depth = deepest = 0
    in_string = escaped = False
    for b in line:
        if in_string:
            if escaped:
                escaped = False
            elif b == 0x5C:  # backslash
                escaped = True
            elif b == 0x22:  # quote
                in_string = False
        elif b == 0x22:
            in_string = True
        elif b in (0x5B, 0x7B):  # [ {
            depth += 1
            if depth > deepest:
                deepest = depth
                if deepest > MAX_DEPTH:
                    break
        elif b in (0x5D, 0x7D):
            depth -= 1
    return deepest


def _bind(path: str) -> socket.socket:
    """A socket only this user can reach: its directory 0700 (made only when it is the
    per-user :func:`runtime_dir`; any other must exist), the socket 0600, both checked to be
    ours (``check_endpoint``).  An endpoint another daemon answers on is not taken over
    (MissingLinkError); a stale one is."""
    from pathlib import Path

    p = Path(path)
    try:
        if os.path.abspath(p.parent) == os.path.abspath(runtime_dir()):
            p.parent.mkdir(mode=0o700, exist_ok=True)
        elif not p.parent.is_dir():
            raise FileNotFoundError(errno.ENOENT, f"no directory {p.parent} (make it first)")
    except OSError as e:
        raise MissingLinkError(f"control endpoint {path}: {e.strerror or e}") from None
    check_endpoint(path)
    if p.exists() or p.is_symlink():
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
        os.chmod(path, 0o600)
    except OSError as e:
        sock.close()
        raise MissingLinkError(f"control endpoint {path}: {e.strerror or e}") from None
    finally:
        os.umask(old)
    sock.listen(MAX_CLIENTS)
    return sock


def _read_line(conn: socket.socket, cap: int, deadline: float) -> bytes | None:
    """One line (without its newline), read by ``deadline`` (TimeoutError after it); None when
    longer than ``cap``."""
    buf = b""
    while b"\n" not in buf:
        left = deadline - _SOCKET_CLOCK.monotonic()
        if left <= 0:
            raise TimeoutError("no whole line in time")
        conn.settimeout(left)
        chunk = conn.recv(65536)
        if not chunk:
            break
        buf += chunk
        if len(buf) > cap:
            return None
    return buf.split(b"\n", 1)[0] or None


def _send(conn: socket.socket, answer: dict[str, Any]) -> None:
    with contextlib.suppress(OSError):  # (a client that went or is too slow: no one to tell)
        conn.sendall(json.dumps(answer).encode() + b"\n")


def ask(path: str, request: dict[str, Any], timeout: float = CLIENT_TIMEOUT) -> dict[str, Any]:
    """One request to the endpoint at ``path``; OSError when nothing answers there, NotOurs
    (before anything is sent) when the endpoint is not this user's."""
    check_endpoint(path)
    sock = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
    sock.settimeout(timeout)
    try:
        sock.connect(path)
        try:
            sock.sendall(json.dumps(request).encode() + b"\n")
        except (BrokenPipeError, ConnectionResetError):
            pass  # turned away before it read (busy): its answer says so
        line = _read_line(sock, MAX_ANSWER, _SOCKET_CLOCK.monotonic() + timeout)
    finally:
        sock.close()
    if line is None:
        raise OSError(f"{path}: no answer")
    answer = json.loads(line)
    if not isinstance(answer, dict):
        raise OSError(f"{path}: not an answer")
    return answer
