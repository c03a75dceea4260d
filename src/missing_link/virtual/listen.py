"""Where a virtual board listens for its host, made once for both kinds of virtual board (the
simulated runtimes of server.py and the board files of boardfile.py): a listening socket for
``tcp://HOST:PORT`` (0: any free port) or ``unix:///PATH`` (a stale socket of an earlier run
is removed, nothing else), and the URL a host opens; or, for a board that dials its host
instead (``--dial``), where it dials."""

from __future__ import annotations

import errno
import logging
import os
import socket
import stat
from typing import Any
from urllib.parse import urlsplit

from ..errors import BadURL
from ..text import safe_text
from ..transport.sockets import parse_host_port

log = logging.getLogger(__name__)


def listen_socket(url: str, backlog: int, *others: str) -> tuple[socket.socket, str]:
    """The listening socket and the URL a host opens; BadURL for a scheme other than tcp and
    unix (``others``: what else the caller takes, for the message), OSError when it cannot be
    bound (FileExistsError: the path is there and is no socket)."""
    scheme = url.split("://", 1)[0]
    if scheme == "tcp":
        parts = urlsplit(url)
        host = parts.hostname or "127.0.0.1"
        try:
            port = parts.port or 0
        except ValueError as e:
            raise BadURL(f"{url!r}: bad port") from e
        sock = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
        sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        where: Any = (host, port)
    elif scheme == "unix":
        path = urlsplit(url).path
        if not path:
            raise BadURL(f"{url!r}: expected unix:///path")
        if os.path.exists(path):
            if not stat.S_ISSOCK(os.stat(path).st_mode):
                raise FileExistsError(errno.EEXIST, f"{path} exists and is not a socket", path)
            os.unlink(path)  # a stale socket of an earlier run: nothing else is removed
        sock = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
        where = path
    else:
        kinds = ["tcp://127.0.0.1:PORT", "unix:///path", *others]
        raise BadURL(f"cannot listen on {url!r}: use {', '.join(kinds[:-1])} or {kinds[-1]}")
    try:
        sock.bind(where)
        sock.listen(backlog)
    except OSError:
        sock.close()
        raise
    if scheme == "unix":
        return sock, f"unix://{where}"
    return sock, f"tcp://{host}:{sock.getsockname()[1]}"


def dial_address(url: str) -> tuple[str, int]:
    """``tcp://HOST:PORT`` (a daemon that runs ``run --listen``) -> (HOST, PORT) a board dials;
    BadURL for anything else."""
    host, port = parse_host_port(url, "dial tcp://HOST:PORT (a daemon that runs run --listen)")
    if not port:
        raise BadURL(f"{url!r}: a board cannot dial port 0")
    return host, port


class AcceptFailures:
    """A virtual board's failed accepts (out of descriptors: EMFILE, which ``board --count N``
    in one process can reach; out of memory; a connection aborted): counted, said once a kind
    on stderr and the count again as the board stops, and the pause before the listener tries
    again (10 ms doubling to 1 s, back to 10 ms once one is taken): the connection stays in
    the backlog, so trying again at once would spin.  One for the CPython board's server and
    one for an AVR board's relay."""

    FIRST_S, LONGEST_S = 0.01, 1.0

    def __init__(self) -> None:
        self.count = 0
        self._pause = self.FIRST_S
        self._said: set[int] = set()

    def failed(self, url: str, e: OSError) -> float:
        """One more failure: how long the listener rests now (s)."""
        self.count += 1
        if (e.errno or 0) not in self._said:
            self._said.add(e.errno or 0)
            log.warning("board %s: accept failed (%s): counted, tried again after a pause",
                        safe_text(url), e.strerror or e)  # fmt: skip
        pause, self._pause = self._pause, min(self._pause * 2, self.LONGEST_S)
        return pause

    def taken(self) -> None:
        self._pause = self.FIRST_S

    def said_at_stop(self, url: str) -> None:
        if self.count:
            log.warning("board %s: %d accepts failed", safe_text(url), self.count)
