"""A Zenoh session's configuration: a native Zenoh config file (TLS and mutual TLS endpoints,
certificates, ``access_control``: docs/security.md), if one is given, with the project's own
keys on top (mode, endpoints, multicast scouting off).  Zenoh does the TLS and the access
control; nothing here reimplements either.  Used by the ``zenoh`` publisher (``[zenoh] config``)
and ``missing-link router --config``."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

from ..errors import ConfigError


def check_endpoints(where: str, endpoints: list[Any]) -> None:
    for ep in endpoints:
        if not isinstance(ep, str) or "://" in ep or "/" not in ep:
            raise ConfigError(f"{where}: {ep!r} is not a Zenoh endpoint (e.g. tcp/127.0.0.1:7447)")


def session_config(
    mode: str, connect: list[str], listen: list[str], native: str | None = None
) -> Any:
    """A ``zenoh.Config``: ``native`` (a Zenoh JSON5 file) first, then ours."""
    import zenoh

    if native:
        path = Path(native).expanduser()
        if not path.is_file():
            raise ConfigError(f"zenoh config {native}: no such file")
        try:
            cfg = zenoh.Config.from_file(str(path))
        except Exception as e:  # noqa: BLE001 - zenoh's own error says what is wrong
            raise ConfigError(f"zenoh config {native}: {e}") from None
    else:
        cfg = zenoh.Config()
    cfg.insert_json5("mode", json.dumps(mode))
    cfg.insert_json5("connect/endpoints", json.dumps(connect))
    cfg.insert_json5("listen/endpoints", json.dumps(listen))
    # never scout by multicast: it reaches every interface, and tests stay on loopback
    cfg.insert_json5("scouting/multicast/enabled", "false")
    return cfg


def loopback_only(endpoints: list[str]) -> bool:
    """Whether every endpoint is on this host's loopback (``tcp/127.0.0.1:7447``,
    ``tls/[::1]:7447``, ``tcp/localhost:7447``)."""
    for ep in endpoints:
        host = ep.split("/", 1)[1].rsplit(":", 1)[0].strip("[]").split("#")[0]
        if not (host.startswith("127.") or host in ("::1", "localhost")):
            return False
    return True


def takes_commands(option: object, loopback: bool, where: str) -> bool:
    """A face's ``commands`` option: true or false, or (absent) whether it is on loopback."""
    if option is None:
        return loopback
    if not isinstance(option, bool):
        raise ConfigError(f"{where}.commands: expected true or false, got {option!r}")
    return option
