"""Publishers by name: a table naming each built-in publisher's module and class, imported on
first use (as python-can names its back ends), with what each needs from the environment.

``available_publishers()`` lists exactly the publishers that can start here, without importing
the heavy libraries to find out (``importlib.util.find_spec`` only looks): ``ros2`` where rclpy
is installed, ``ros1`` where rospy is, ``zenoh`` where eclipse-zenoh is.  ``make_publisher``
imports the one asked for; a missing library or a failed import is one line naming the
publisher and what to install.  Third-party publishers register through the
``missing_link.publishers`` entry-point group or :func:`register_publisher`.
"""

from __future__ import annotations

import importlib
import importlib.util
import math
import os
import sys
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from ..errors import ConfigError
from ..text import did_you_mean
from .base import Publisher, PublisherError

Factory = Callable[[dict[str, Any]], Publisher]

#: where Debian's ROS 1 (python3-rospy) puts rospy; a 3.11 venv can use it (see ros1.py)
DEBIAN_DIST = "/usr/lib/python3/dist-packages"


@dataclass(frozen=True)
class Entry:
    module: str
    cls: str
    needs: tuple[str, ...] = ()  #: top-level modules that must be importable
    hint: str = ""  #: how to get them (the package's extra, where it has one)
    #: the ``[daemon]`` settings the face takes unless its own table sets them (``distro``: every
    #: face), as the daemon hands them over (``daemon_settings``)
    daemon: tuple[str, ...] = ()


BUILTIN: dict[str, Entry] = {
    "bus": Entry("missing_link.publishers.bus", "Bus"),
    "console": Entry("missing_link.publishers.console", "ConsolePublisher"),
    "mcap": Entry(
        "missing_link.publishers.mcap", "McapPublisher", ("rosbags", "mcap"), "pip install mcap"
    ),
    "zenoh": Entry(
        "missing_link.publishers.zenoh",
        "ZenohPublisher",
        ("zenoh", "xxhash", "rosbags"),
        "pip install 'missing-link[zenoh]'",
        ("node",),
    ),
    "foxglove": Entry(
        "missing_link.publishers.foxglove",
        "FoxglovePublisher",
        ("websockets", "rosbags"),
        "pip install 'missing-link[web]'",
    ),
    "web": Entry(
        "missing_link.publishers.web",
        "WebPublisher",
        ("websockets",),
        "pip install 'missing-link[web]'",
    ),
    "ros1": Entry(
        "missing_link.publishers.ros1",
        "Ros1Publisher",
        ("rospy",),
        "scripts/system-deps.sh --ros1 (Debian's ros-core and python3-rospy)",
        ("node",),
    ),
    "ros2": Entry(
        "missing_link.publishers.ros2",
        "Ros2Publisher",
        ("rclpy",),
        "source your ROS 2 installation, or pip install 'missing-link[ros2]'",
        ("node",),
    ),
}
_REGISTERED: dict[str, Factory] = {}

#: every option each built-in publisher reads (its ``[name]`` table in the daemon's config), by
#: type: a key not here is a typo the publisher would ignore (``[zenoh] comands = false`` left
#: commands on), so it is an error naming the key.  ``distro`` (all) and ``node`` (the ROS
#: faces) come from ``[daemon]`` unless the table sets them.  tests/test_config_faces.py reads
#: each publisher's source and holds this table to what it reads.
OPTIONS: dict[str, dict[str, str]] = {
    "bus": {"distro": "text"},
    "console": {"distro": "text", "rate_hz": "number"},
    "mcap": {"distro": "text", "path": "path", "prefix": "text", "rotate_mb": "number",
             "rotate_s": "number", "chunk_s": "number", "close_timeout": "number",
             "queue": "number", "replay": "bool"},
    "zenoh": {"distro": "text", "node": "text", "domain": "integer", "mode": "text",
              "connect": "texts", "listen": "texts", "config": "path", "commands": "bool"},
    "foxglove": {"distro": "text", "name": "text", "host": "text", "port": "integer",
                 "origins": "texts"},
    "ros1": {"distro": "text", "node": "text", "master_uri": "text", "ros_ip": "text",
             "queue_size": "integer", "commands": "bool"},
    "ros2": {"distro": "text", "node": "text", "prefix": "path", "depth": "integer",
             "commands": "bool"},
    "web": {"distro": "text", "host": "text", "port": "integer", "commands": "bool",
            "cert": "path", "key": "path", "token_file": "path", "origins": "texts",
            "hosts": "texts", "name": "text"},
}  # fmt: skip
_RANGES = {"domain": (0, 232), "port": (0, 65535), "depth": (1, 100_000),
           "queue_size": (1, 100_000)}  # fmt: skip


def check_options(name: str, options: dict[str, Any]) -> None:
    """Refuse an unknown key or a value of the wrong type in a built-in publisher's options
    (ConfigError naming ``[name] key``); a third-party publisher checks its own."""
    known = OPTIONS.get(name)
    if known is None or name in _REGISTERED:
        return
    for key, value in options.items():
        at = f"[{name}].{key}"
        kind = known.get(key)
        if kind is None:
            raise ConfigError(
                f"{at}: unknown key{did_you_mean(key, known)} (keys of [{name}]: "
                f"{', '.join(known)})"
            )
        if not _is(kind, value):
            raise ConfigError(f"{at}: expected {_KINDS[kind]}, got {value!r}")
        if key in _RANGES and not _RANGES[key][0] <= value <= _RANGES[key][1]:
            raise ConfigError(f"{at}: {value!r} is outside {_RANGES[key][0]}..{_RANGES[key][1]}")


_KINDS = {"text": "a string", "path": "a string (a path)", "number": "a number",
          "integer": "an integer", "bool": "true or false",
          "texts": "a list of strings"}  # fmt: skip


def _is(kind: str, value: Any) -> bool:
    if kind == "bool":
        return isinstance(value, bool)
    if isinstance(value, bool):
        return False
    if kind == "text":
        return isinstance(value, str)
    if kind == "path":  # (a Path from code is one too)
        return isinstance(value, (str, os.PathLike))
    if kind == "integer":
        return isinstance(value, int)
    if kind == "number":
        return isinstance(value, (int, float)) and math.isfinite(value)
    return isinstance(value, list) and all(isinstance(v, str) for v in value)


def register_publisher(name: str, factory: Factory) -> None:
    """Make ``name`` start ``factory(options)`` (a plugin that is not an entry point)."""
    _REGISTERED[name] = factory


def _importable(module: str) -> bool:
    if module == "rospy" and debian_rospy():
        return True
    try:
        return importlib.util.find_spec(module) is not None
    except (ImportError, ValueError):
        return False


def debian_rospy() -> bool:
    """Debian's rospy is usable from this Python (the same minor version as the system's)."""
    return sys.version_info[:2] == (3, 11) and os.path.isdir(f"{DEBIAN_DIST}/rospy")


def missing(name: str) -> list[str]:
    """What built-in publisher ``name`` needs and this environment lacks ([]: nothing)."""
    entry = BUILTIN.get(name)
    return [] if entry is None else [m for m in entry.needs if not _importable(m)]


def _entry_points() -> dict[str, Any]:
    from importlib.metadata import entry_points

    return {ep.name: ep for ep in entry_points(group="missing_link.publishers")}


def known_publishers() -> list[str]:
    """Every publisher name this installation knows, available here or not (a config file may
    name ``ros2`` on a machine without rclpy: the daemon then says what is missing)."""
    return sorted({*BUILTIN, *_REGISTERED, *_entry_points()})


def available_publishers() -> list[str]:
    """The publishers that can start in this environment, by name."""
    names = {n for n in BUILTIN if not missing(n)} | set(_REGISTERED) | set(_entry_points())
    return sorted(names)


def unavailable(name: str) -> str | None:
    """Why ``name`` cannot start here (one line), or None when it can."""
    if name in _REGISTERED or (name in BUILTIN and not missing(name)):
        return None
    if name in BUILTIN:
        lacking = ", ".join(missing(name))
        return f"needs {lacking}, which is not installed here ({BUILTIN[name].hint})"
    if name in _entry_points():
        return None
    return f"unknown (available here: {', '.join(available_publishers())})"


def daemon_settings(name: str) -> tuple[str, ...]:
    """The ``[daemon]`` settings publisher ``name`` takes besides its own options (``distro``
    for every face; ``node`` for the ROS faces), as its entry declares them."""
    entry = BUILTIN.get(name)
    return ("distro", *(entry.daemon if entry is not None else ()))


def make_publisher(name: str, options: dict[str, Any]) -> Publisher:
    """Start publisher ``name`` with ``options``; ``PublisherError`` when it cannot be had,
    ``ConfigError`` for an option it does not know or of the wrong type."""
    check_options(name, options)  # (the config file's are checked when it is read, too)
    factory = _REGISTERED.get(name)
    if factory is None:
        why = unavailable(name)
        if why is not None:
            raise PublisherError(f"publisher {name}: {why}")
        entry = BUILTIN.get(name)
        if entry is not None:
            factory = getattr(importlib.import_module(entry.module), entry.cls)
        else:
            factory = _entry_points()[name].load()
    assert factory is not None
    return factory(options)
