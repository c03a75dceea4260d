"""The device console in the browser (docs/web.md): one page that shows every board, its
transducers with a plot of the last 30 s, its configuration (set, save, reset), its actuators
(where commands are on for this face) and the recording; live over a WebSocket.

``missing-link run ... --web [ADDR:PORT]`` (127.0.0.1:8080) or ``publishers = ["web"]`` with a
``[web]`` table: ``host``, ``port``, ``commands`` (true or false; by default true only on
loopback, as on every face: daemon/control/allowlist.py), ``cert`` and ``key`` (TLS, PEM files),
``token_file`` (a file holding the token a person logs in with, mode 0600: ``missing-link key
new FILE`` makes one), ``origins`` (other sites whose pages may connect, e.g. a reverse proxy's)
and ``hosts`` (names the console answers to besides loopback ones).  An address that is not
loopback needs TLS and a token: the console refuses to start without them.

The face is a publisher (topics, updates, command topics, configuration offers: base.py) and is
handed the daemon's public verbs when the daemon starts it (``start(api)``, a
:class:`~missing_link.publishers.base.DaemonApi`): the status a few times a second, and
setting, saving and resetting a board's configuration.  Until then the page shows the status of
each ``/diagnostics`` round and the configuration read-only.
"""

from __future__ import annotations

import logging
import os
import stat
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import Any

from ..descriptors import read_input_file
from ..errors import ConfigError
from ..host.board_log import LogLine
from ..host.config import ConfigKey, Value
from ..topics import Topic, Update
from .base import ApplyConfig, DaemonApi, Publisher, PublisherError
from .front_door import is_loopback
from .registry import check_options
from .web_model import ConsoleModel

log = logging.getLogger(__name__)

DEFAULT_HOST, DEFAULT_PORT = "127.0.0.1", 8080
MIN_TOKEN = 16  #: characters a token has at least


@dataclass
class WebOptions:
    host: str = DEFAULT_HOST
    port: int = DEFAULT_PORT
    commands: bool = True
    cert: str = ""
    key: str = ""
    token: str = field(default="", repr=False)  #: never logged, never in a URL
    origins: list[str] = field(default_factory=list)
    hosts: list[str] = field(default_factory=list)
    name: str = "missing-link"

    @property
    def tls(self) -> bool:
        return bool(self.cert)

    @property
    def url(self) -> str:
        host = f"[{self.host}]" if ":" in self.host else self.host
        return f"{'https' if self.tls else 'http'}://{host}:{self.port}/"


def parse_addr(text: str) -> tuple[str, int]:
    """``ADDR:PORT``, ``[v6]:PORT``, ``ADDR`` or ``PORT`` -> (host, port)."""
    text = text.strip()
    if text.isdigit():
        return DEFAULT_HOST, int(text)
    if text.startswith("["):
        host, _, rest = text[1:].partition("]")
        port = rest[1:] if rest.startswith(":") else str(DEFAULT_PORT)
    elif text.count(":") == 1:
        host, port = text.split(":")
    else:
        host, port = text, str(DEFAULT_PORT)
    if not host or not port.isdigit() or not 0 <= int(port) <= 65535:
        raise ConfigError(f"--web {text!r}: expected ADDR:PORT, e.g. 127.0.0.1:8080")
    return host, int(port)


#: bytes a token file may have (a token is a line; /dev/zero is refused before it is read)
MAX_TOKEN_FILE = 4096


def _read_token(path: str) -> str:
    try:
        st = os.stat(path)
        token = read_input_file(path, MAX_TOKEN_FILE).decode("utf-8").strip()  # (capped)
    except (OSError, ValueError) as e:  # (UnicodeDecodeError is a ValueError)
        raise ConfigError(f"[web] token_file {path}: cannot read: {e}") from None
    if st.st_mode & (stat.S_IRWXG | stat.S_IRWXO):
        raise ConfigError(f"[web] token_file {path}: others may read it (chmod 600 {path})")
    if len(token) < MIN_TOKEN or not token.isprintable():
        raise ConfigError(
            f"[web] token_file {path}: at least {MIN_TOKEN} printable characters "
            "(missing-link key new FILE makes one)"
        )
    return token


def parse_options(opts: Mapping[str, Any]) -> WebOptions:
    """The ``[web]`` table (and what ``--web`` put in it); ConfigError naming the key."""
    # keys and types by the registry's table, as on every face (a typo in `commands` must
    # not leave them on)
    check_options("web", dict(opts))
    o = WebOptions(origins=list(opts.get("origins", [])), hosts=list(opts.get("hosts", [])))
    o.host = str(opts.get("host", DEFAULT_HOST))
    o.port = int(opts.get("port", DEFAULT_PORT))
    o.name = str(opts.get("name", o.name))
    o.cert, o.key = str(opts.get("cert", "")), str(opts.get("key", ""))
    if bool(o.cert) != bool(o.key):
        raise ConfigError("[web] cert and key: give both (PEM files) or neither")
    if opts.get("token_file"):
        o.token = _read_token(str(opts.get("token_file")))
    loopback = is_loopback(o.host)
    if not loopback and not (o.tls and o.token):
        raise ConfigError(
            f"[web] host {o.host}: not loopback, so the console needs TLS (cert, key) and a "
            "token (token_file): docs/web.md"
        )
    commands = bool(opts.get("commands", loopback))
    o.commands = commands
    return o


class WebPublisher(Publisher):
    name = "web"

    def __init__(self, options: dict[str, Any] | None = None) -> None:
        from .web_server import WebServer  # (websockets, asyncio: only when asked)

        self.options = parse_options(options or {})
        self.takes_commands = self.options.commands
        self.model = ConsoleModel()
        try:
            self.server = WebServer(self.model, self.options, self._commands_on, self.faults)
        except OSError as e:
            raise PublisherError(f"web: cannot listen on {self.options.host}: {e}") from None
        self.options.port = self.server.port
        self.url = self.options.url
        log.info("web: console at %s", self.url)

    def _commands_on(self) -> bool:
        return bool(self.takes_commands)

    def start(self, api: DaemonApi) -> None:
        """The daemon's verbs: status polled while pages are open; configuration changes."""
        self.server.attach(api)

    # ---- the publisher interface ---------------------------------------------------------------
    def add_topic(self, topic: Topic) -> None:
        self.model.add_topic(topic)

    def add_command_topic(self, name: str, topic: Topic, deliver: Callable[[Any], None]) -> None:
        self.model.add_command(name, topic, deliver)

    def publish(self, update: Update) -> None:
        self.model.add_sample(update)

    def log(self, line: LogLine) -> None:
        self.model.add_log(line)

    def diagnostics(self, status: list[dict[str, Any]], now_ns: int) -> None:
        if not self.server.attached:  # (attached: polled faster, see WebServer)
            boards = [s for s in status if "board" in s]
            self.model.set_status(boards, [s for s in status if "publisher" in s])

    def add_config(
        self, board: str, keys: list[ConfigKey], values: dict[str, Value], apply: ApplyConfig
    ) -> None:
        self.model.add_config(board, keys, values)

    def config_changed(self, board: str, values: dict[str, Value]) -> None:
        self.model.config_changed(board, values)
        ctx = self.server.ctx
        if ctx is not None:  # (the saved state with this change: web_model.py says why)
            self.model.observe(ctx.status())

    def close(self) -> None:
        self.server.close()

    def status(self) -> dict[str, Any]:
        s = self.server
        return {
            **super().status(),
            "url": self.url,
            "dropped": self.model.dropped() + s.dropped,
            "clients": s.clients,
            "commands_on": self.takes_commands,
            "commands_sent": s.commands_sent,
            "origins_refused": s.door.refused_origins,
            "hosts_refused": s.door.refused_hosts,
            "clients_refused": s.door.refused_clients,
            "logins_refused": s.logins.refused,
            "sockets_refused": s.logins.sockets_refused,
            "pages_closed": s.pages_closed,
            "client_messages_dropped": s.dropped_messages,
        }
