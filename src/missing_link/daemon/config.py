"""Daemon configuration (TOML), validated: every error names the file, the table and the key.

See ``examples/missing-link.toml`` for a complete, commented example.
"""

from __future__ import annotations

import math
import re
import tomllib
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from ..descriptors import read_input_file
from ..errors import ConfigError
from ..publishers.registry import check_options, known_publishers
from ..ros.msgs import DISTROS, check_package
from ..ros.standard import StdOptions
from ..text import did_you_mean, is_token
from ..topics import check_topic
from .discover_spec import DiscoverSpec, parse_usb_id
from .listen_spec import ListenSpec, parse_listen
from .paths import runtime_dir
from .ros_config import JointsConfig, parse_joints, parse_ros


@dataclass
class BoardSpec:
    url: str
    name: str | None = None  #: topic prefix; default: the board's board.name property
    descriptors: str | None = None  #: host-side descriptor file (original boards)
    timeout: float = 1.0  #: s per call
    handshake_timeout: float = 5.0  #: s for mapping, properties and descriptors together
    #: s without an intact frame from the board before the link is declared stale (frozen
    #: board, half-open link) and reconnected; heartbeats go out after half of it
    link_timeout: float = 1.5
    #: UART baud rate when the board is on a real UART (an FTDI-like bridge): the time its
    #: replies spend on the wire is then known to clock sync.  0: not a UART, or unknown.
    uart_baud: int = 0
    #: ms the reader gathers SIFs while they stream in, to read several per wake-up (host CPU
    #: per update falls; sample latency grows by at most this; replies are never delayed)
    batch_ms: float = 2.0

    @property
    def byte_ns(self) -> float:
        return 10e9 / self.uart_baud if self.uart_baud > 0 else 0.0


#: a board.id as a board states it and a config names it: printable ASCII, no spaces
BOARD_ID = re.compile(r"[!-~]{1,64}\Z")


@dataclass
class Config:
    boards: list[BoardSpec] = field(default_factory=list)
    publishers: list[str] = field(default_factory=lambda: ["bus"])
    node: str = "missing_link"
    distro: str = "jazzy"
    package: str = "missing_link_msgs"
    remap: dict[str, str] = field(default_factory=dict)
    publisher_options: dict[str, dict[str, Any]] = field(default_factory=dict)
    backoff_min: float = 0.2
    #: reconnect attempts back off up to this (s): a board that comes back is up again within
    #: about this plus its handshake
    backoff_max: float = 1.0
    diagnostics_period: float = 1.0
    #: clock exchanges per second for all boards together once their maps are tracking (each
    #: board probes at most every boards / probe_budget s; bursts after a connect, a reset or
    #: a surprise are not limited): bounds the sync's CPU with many boards
    probe_budget: float = 100.0
    #: find boards as their serial ports appear ([discover]; ``run --auto``)
    discover: DiscoverSpec | None = None
    #: run-time configuration per board name ([boards.<name>.config]): applied at every
    #: connect and after every board reset (docs/configuration.md)
    board_config: dict[str, dict[str, bool | int | float | str]] = field(default_factory=dict)
    #: the local control endpoint (a unix socket) through which ``missing-link config``,
    #: ``call`` and ``info`` reach the boards this daemon holds; "" = none (docs/cli.md)
    control: str | None = None
    #: the command topics that take commands at all, from any face (patterns;
    #: daemon/control/allowlist.py)
    commands: list[str] = field(default_factory=lambda: ["**"])
    #: every transducer's standard types beside its thesis-format topic (ros/standard), and
    #: the thesis-format topics: either can be turned off daemon-wide or per transducer
    standard_types: bool = True
    thesis_types: bool = True
    #: host-side keys per board and transducer ([boards.<name>.ros.<transducer>]: frame_id, ...)
    ros: dict[str, dict[str, StdOptions]] = field(default_factory=dict)
    #: the robot-level JointState in and out ([joints]; daemon/joints.py), None: none
    joints: JointsConfig | None = None
    #: board name -> the board.id it is ([boards.<name>] id): the board keeps its name, topics
    #: and configuration whatever port or link it comes on
    board_ids: dict[str, str] = field(default_factory=dict)
    #: accept boards that dial in here (``run --listen``; intake/listener.py)
    listen: str | None = None
    #: which boards that dial in are taken: "any", or "known" (those with an id above)
    accept: str = "any"
    #: s a board that dialed in with an id the config does not name is kept after it left
    #: (then its session and name go: intake/dialin.py); configured ids are kept for good
    dialin_expire: float = 300.0
    #: boards of ids the config does not name held at once; more are refused, saying so
    dialin_max: int = 64
    source: str = "<defaults>"

    def std_options(self, board: str, transducer: str) -> StdOptions:
        """The host-side keys of one transducer, with the daemon-wide switches applied."""
        o = self.ros.get(board, {}).get(transducer, StdOptions())
        if self.standard_types and self.thesis_types:
            return o
        return StdOptions(
            o.frame_id,
            o.standard and self.standard_types,
            o.thesis and self.thesis_types,
            o.counts_per_rev,
            o.field_of_view,
        )

    def name_of_id(self, board_id: str) -> str | None:
        """The configured name of the board whose board.id is ``board_id``."""
        for name, known in self.board_ids.items():
            if known == board_id:
                return name
        return None

    def listen_spec(self) -> ListenSpec | None:
        return parse_listen(self.listen) if self.listen else None


_TABLES = ("daemon", "board", "boards", "remap", "discover", "joints")
_DAEMON_KEYS = {
    "publishers": list,
    "node": str,
    "distro": str,
    "package": str,
    "backoff_min": (int, float),
    "backoff_max": (int, float),
    "diagnostics_period": (int, float),
    "probe_budget": (int, float),
    "control": str,
    "commands": list,
    "standard_types": bool,
    "thesis_types": bool,
    "listen": str,
    "accept": str,
    "dialin_expire": (int, float),
    "dialin_max": int,
}
_BOARD_KEYS = {
    "url": str,
    "name": str,
    "descriptors": str,
    "timeout": (int, float),
    "handshake_timeout": (int, float),
    "link_timeout": (int, float),
    "uart_baud": int,
    "batch_ms": (int, float),
}
#: (low, high) for numbers: a value outside is refused with the file, table and key
_RANGES: dict[str, tuple[float, float]] = {
    "backoff_min": (0.01, 60.0),
    "backoff_max": (0.01, 3600.0),
    "diagnostics_period": (0.05, 3600.0),
    "probe_budget": (1.0, 100_000.0),
    "timeout": (0.001, 60.0),
    "handshake_timeout": (0.1, 600.0),
    "link_timeout": (0.05, 3600.0),
    "uart_baud": (0, 100_000_000),
    "batch_ms": (0.0, 100.0),
    "dialin_expire": (0.0, 30 * 86400.0),
    "dialin_max": (1, 100_000),
}


def _type_name(t: Any) -> str:
    if isinstance(t, tuple):
        return "number"
    return {list: "list", str: "string"}.get(t, str(t.__name__))


Fail = Callable[[str, str], ConfigError]


def parse_config(doc: dict[str, Any], source: str = "<config>") -> Config:
    """A Config from a parsed TOML document; every wrong key, type or value is a ConfigError
    naming the file, the table and the key (one line, never a traceback)."""
    cfg = Config(source=source)

    def fail(where: str, why: str) -> ConfigError:
        return ConfigError(f"{source}: {where}: {why}")

    cfg.board_config, cfg.ros, cfg.board_ids = _parse_boards(doc.get("boards", {}), fail)
    if "joints" in doc:
        cfg.joints = parse_joints(doc["joints"], fail, _check_table)
    if "discover" in doc:
        cfg.discover = _parse_discover(doc["discover"], fail)
    _parse_daemon(cfg, doc.get("daemon", {}), fail)
    cfg.boards = _parse_board_tables(doc.get("board", []), fail)
    cfg.remap = _parse_remap(doc.get("remap", {}), fail)
    cfg.publisher_options = _parse_publisher_tables(doc, fail, source)
    return cfg


def _check_table(table: Any, allowed: dict[str, Any], where: str, fail: Fail) -> dict[str, Any]:
    if not isinstance(table, dict):
        raise fail(where, "must be a table")
    for key, value in table.items():
        if key not in allowed:
            raise fail(
                f"{where}.{key}",
                f"unknown key{did_you_mean(key, allowed)} (known: {', '.join(allowed)})",
            )
        if not isinstance(value, allowed[key]) or (
            isinstance(value, bool) and allowed[key] is not bool
        ):
            raise fail(f"{where}.{key}", f"expected a {_type_name(allowed[key])}, got {value!r}")
        if isinstance(value, float) and not math.isfinite(value):
            raise fail(f"{where}.{key}", f"expected a finite number, got {value!r}")
        if key in _RANGES:
            lo, hi = _RANGES[key]
            if not lo <= value <= hi:
                raise fail(f"{where}.{key}", f"{value!r} is outside {lo:g}..{hi:g}")
    return table


def _parse_daemon(cfg: Config, daemon: Any, fail: Fail) -> None:
    for key, value in _check_table(daemon, _DAEMON_KEYS, "daemon", fail).items():
        seconds = type(value) is int and key != "dialin_max"
        setattr(cfg, key, float(value) if seconds else value)  # 1 -> 1.0 (seconds)
    if not all(isinstance(c, str) and c[:1] in ("/", "*") for c in cfg.commands):
        raise fail("daemon.commands", 'command topics or patterns, e.g. ["/rover/*/cmd"]')
    _check_control(cfg.control, fail)
    if cfg.accept not in ("any", "known"):
        raise fail("daemon.accept", f'{cfg.accept!r}: "any" or "known" (ids in [boards.NAME])')
    if cfg.listen is not None:
        try:
            parse_listen(cfg.listen)
        except ValueError as e:  # (BadURL too: the key file)
            raise fail("daemon.listen", str(e)) from None
    if cfg.backoff_max < cfg.backoff_min:
        raise fail("daemon.backoff_max", f"{cfg.backoff_max:g} is below backoff_min")
    if cfg.distro not in DISTROS:
        raise fail("daemon.distro", f"{cfg.distro!r} is not one of {', '.join(DISTROS)}")
    try:
        check_package(cfg.package)
    except ValueError as e:
        raise fail("daemon.package", str(e)) from None
    known_pubs = known_publishers()
    for name in cfg.publishers:
        if not isinstance(name, str) or name not in known_pubs:
            raise fail(
                "daemon.publishers",
                f"unknown publisher {name!r}{did_you_mean(name, known_pubs)} (available: "
                f"{', '.join(known_pubs)})",
            )


def _check_control(control: str | None, fail: Fail) -> None:
    """``control``: "" (none) or an absolute socket path in a directory that exists, unless
    it is the per-user runtime directory; no other directory is created for it."""
    if not control:
        return
    if not control.startswith("/"):
        raise fail("daemon.control", f'{control!r}: an absolute path of a socket, or ""')
    parent = Path(control).parent
    if parent != Path(runtime_dir()) and not parent.is_dir():
        raise fail(
            "daemon.control",
            f"{control!r}: its directory {parent} does not exist (the daemon creates only "
            f"{runtime_dir()}, its default; make the directory first)",
        )


def _parse_board_tables(boards: Any, fail: Fail) -> list[BoardSpec]:
    if not isinstance(boards, list):
        raise fail("board", "use [[board]] tables, one per board")
    out: list[BoardSpec] = []
    for k, b in enumerate(boards, start=1):
        where = f"[[board]] #{k}"
        _check_table(b, _BOARD_KEYS, where, fail)
        if "url" not in b:
            raise fail(where, "missing url")
        if "name" in b and not is_token(b["name"]):
            raise fail(f"{where}.name", f"{b['name']!r} is not a topic name ([a-z][a-z0-9_]*)")
        if "name" in b and any(o.name == b["name"] for o in out):  # (one board's topics)
            raise fail(f"{where}.name", f"{b['name']!r}: another [[board]] has this name")
        out.append(BoardSpec(**b))
    return out


def _parse_remap(remap: Any, fail: Fail) -> dict[str, str]:
    if not isinstance(remap, dict):
        raise fail("remap", 'must be a table of "/old/topic" = "/new/topic"')
    for old, new in remap.items():
        try:
            if not isinstance(new, str):
                raise ValueError(f"expected a topic name like /board/sensor, got {new!r}")
            check_topic(old)
            check_topic(new)
        except ValueError as e:
            raise fail(f"remap.{old!r}", str(e)) from None
    return dict(remap)


def _parse_publisher_tables(
    doc: dict[str, Any], fail: Fail, source: str
) -> dict[str, dict[str, Any]]:
    """Every other table is a publisher's options, checked against what it reads."""
    known_pubs = known_publishers()
    out = {}
    for table, value in doc.items():
        if table in _TABLES:
            continue
        if table not in known_pubs:
            raise fail(
                table,
                f"unknown table{did_you_mean(table, [*_TABLES, *known_pubs])} (tables: "
                f"{', '.join(_TABLES)}, {', '.join(known_pubs)})",
            )
        if not isinstance(value, dict):
            raise fail(table, "must be a table of publisher options")
        try:
            check_options(table, value)
        except ConfigError as e:
            raise ConfigError(f"{source}: {e}") from None
        out[table] = dict(value)
    return out


_CONFIG_KEY = re.compile(r"[a-z][a-z0-9_]*\.[a-z][a-z0-9_]*\Z")


Settings = dict[str, dict[str, bool | int | float | str]]


def _parse_boards(
    table: Any, fail: Any
) -> tuple[Settings, dict[str, dict[str, StdOptions]], dict[str, str]]:
    """``[boards.<name>]``: ``id = "..."`` (the board.id of the board so named),
    ``[boards.<name>.config]``: keys ``"<transducer>.<key>" = value`` per board name (checked
    against the board's own table when it connects); ``[boards.<name>.ros.<transducer>]``: the
    host-side keys of its standard types (docs/ros.md)."""
    if not isinstance(table, dict):
        raise fail("boards", "must be tables like [boards.thesis.config]")
    out: Settings = {}
    ros: dict[str, dict[str, StdOptions]] = {}
    ids: dict[str, str] = {}
    for name, sub in table.items():
        where = f"boards.{name}"
        if not is_token(name):
            raise fail(where, f"{name!r} is not a board name ([a-z][a-z0-9_]*)")
        if not isinstance(sub, dict) or set(sub) - {"config", "ros", "id"}:
            odd = sorted(set(sub) - {"config", "ros", "id"}) if isinstance(sub, dict) else []
            near = did_you_mean(odd[0], ("config", "ros", "id")) if odd else ""
            raise fail(
                f"{where}.{odd[0]}" if odd else where,
                f"unknown key{near}: [boards.NAME] has two tables, config and ros "
                '([boards.NAME.config]), and an id = "..."',
            )
        if "id" in sub:
            ids[name] = _board_id(sub["id"], ids, f"{where}.id", fail)
        values = sub.get("config", {})
        if not isinstance(values, dict):
            raise fail(f"{where}.config", 'must be a table of "transducer.key" = value')
        for key, value in values.items():
            if not _CONFIG_KEY.match(key):
                raise fail(f"{where}.config.{key}", 'keys are "<transducer>.<key>", quoted')
            if not isinstance(value, (bool, int, float, str)):
                raise fail(f"{where}.config.{key}", f"expected a value, got {value!r}")
        out[name] = dict(values)
        if "ros" in sub:
            ros[name] = parse_ros(sub["ros"], f"{where}.ros", fail, _check_table)
    return out, ros, ids


def _board_id(value: Any, ids: dict[str, str], where: str, fail: Any) -> str:
    if not isinstance(value, str) or not BOARD_ID.match(value):
        raise fail(where, f"a board.id (printable ASCII without spaces, 1..64), not {value!r}")
    for other, known in ids.items():
        if known == value:
            raise fail(where, f"{value!r} is the id of boards.{other} already")
    return value


def _parse_discover(table: Any, fail: Any) -> DiscoverSpec:
    if not isinstance(table, dict):
        raise fail("discover", "must be a table")
    spec = DiscoverSpec()
    types: dict[str, Any] = {
        "ports": list, "ids": list, "vid": int, "pid": int, "serial": str, "any_usb": bool,
        "usb_only": bool, "interval": (int, float), "probe_timeout": (int, float),
        "uart_baud": int,
    }  # fmt: skip
    ranges = {"interval": (0.05, 60.0), "probe_timeout": (0.1, 60.0), "vid": (0, 0xFFFF),
              "pid": (0, 0xFFFF), "uart_baud": (0, 100_000_000)}  # fmt: skip
    for key, value in table.items():
        if key not in types:
            raise fail(
                f"discover.{key}",
                f"unknown key{did_you_mean(key, types)} (known: {', '.join(types)})",
            )
        want = types[key]
        if not isinstance(value, want) or (isinstance(value, bool) and want is not bool):
            raise fail(f"discover.{key}", f"expected {_type_name(want)}, got {value!r}")
        if key in ranges and not ranges[key][0] <= value <= ranges[key][1]:
            raise fail(
                f"discover.{key}", f"{value!r} is outside {ranges[key][0]:g}..{ranges[key][1]:g}"
            )
        if key == "ports" and not all(isinstance(g, str) and g for g in value):
            raise fail("discover.ports", "must be a list of device globs like '/dev/ttyACM*'")
        if key == "ids":
            try:
                value = [parse_usb_id(str(i)) for i in value]
            except ValueError as e:
                raise fail("discover.ids", str(e)) from None
        setattr(spec, key, float(value) if key in ("interval", "probe_timeout") else value)
    return spec


def load_config(path: str) -> Config:
    try:
        text = read_input_file(path).decode("utf-8")
    except OSError as e:
        raise ConfigError(f"{path}: cannot read: {e.strerror}") from None
    except ValueError as e:  # (UnicodeDecodeError too)
        raise ConfigError(f"{path}: refused: {e}") from None
    try:
        doc = tomllib.loads(text)
    except tomllib.TOMLDecodeError as e:
        raise ConfigError(f"{path}: not valid TOML: {e}") from None
    except RecursionError:  # (tomllib recurses per level: "a = [[[[..." 5,000 deep)
        raise ConfigError(f"{path}: not valid TOML: nested too deeply") from None
    return parse_config(doc, path)
