"""Every command's arguments and where its code is: the light table the parser is built from.

Nothing here imports a command's code.  A command names its handler as ``"module:function"``
in this package, imported only when that command runs (main.py), so ``missing-link call``
loads the J2A client and nothing of the daemon, numpy, zenoh or rich.  Every number a command
hands a board or the daemon is checked here (common.py): finite, in range, one line if not.
"""

from __future__ import annotations

import argparse
from collections.abc import Callable
from typing import Any, NamedTuple

from . import board_args
from .common import add_timeout, count_arg, parse_hex, port_arg, positive, seconds_arg

Parser = argparse.ArgumentParser


class Command(NamedTuple):
    name: str
    help: str
    handler: str  #: "module:function" in missing_link.cli, imported when the command runs
    arguments: Callable[[Parser], None]
    description: str | None = None


def _url(sp: Parser) -> None:
    """The board URL and the per-call timeout: every command that talks to one board."""
    sp.add_argument("url", help="board URL, e.g. serial:///dev/ttyACM0 or tcp://127.0.0.1:5000")
    add_timeout(sp)


def _info(sp: Parser) -> None:
    _url(sp)
    sp.add_argument("--json", action="store_true", help="machine-readable output (docs/cli.md)")


def _call(sp: Parser) -> None:
    _url(sp)
    sp.add_argument("name", help="function name, e.g. a2jEcho")
    sp.add_argument(
        "--hex", type=parse_hex, default=b"", help="request payload as hex bytes (28 is 0x28 = 40)"
    )
    sp.add_argument(
        "--value",
        help="one value in the data type of the actuator this function drives (40 is 40, as "
        "send(topic, 40) sends it)",
    )
    sp.add_argument("--json", action="store_true")
    sp.add_argument(
        "--any-code",
        action="store_true",
        help="exit 0 whatever the function returns (default: 1 unless it returns OK)",
    )


def _listen(sp: Parser) -> None:
    _url(sp)
    sp.add_argument("--count", type=count_arg, default=0, help="stop after N samples")
    sp.add_argument("--duration", type=seconds_arg, default=0, help="stop after S seconds")
    sp.add_argument("--transducer", "-t", action="append", help="only this transducer (repeatable)")
    sp.add_argument("--missing", action="store_true", help="also print N/A channels")
    sp.add_argument("--json", action="store_true", help="one JSON object per line")


def _sync(sp: Parser) -> None:
    _url(sp)
    sp.add_argument("--duration", type=seconds_arg, default=0, help="stop after S seconds")
    sp.add_argument("--period", type=positive, default=1.0, help="seconds between lines (1.0)")
    sp.add_argument(
        "--uart-baud", type=count_arg, default=0, help="baud rate if the link is a UART"
    )
    sp.add_argument("--json", action="store_true", help="one JSON object per line")


def _config(sp: Parser) -> None:
    sp.add_argument("url", metavar="TARGET", help="board URL or (through a daemon) board name")
    sp.add_argument("assign", nargs="*", metavar="KEY=VALUE", help="e.g. dist_ir.rate_hz=10")
    sp.add_argument("--save", action="store_true", help="keep the result on the board")
    sp.add_argument("--reset", action="store_true", help="the board file's defaults first")
    sp.add_argument(
        "--erase", action="store_true", help="with --reset: forget the saved configuration too"
    )
    sp.add_argument("--json", action="store_true", help="machine-readable output (docs/cli.md)")
    sp.add_argument("--verbose", "-v", action="store_true", help="defaults, limits and state too")
    add_timeout(sp)


def _create_msgs(sp: Parser) -> None:
    sp.add_argument(
        "source",
        nargs="*",
        help="board URLs and/or descriptor files (.toml or transds/1 text), in order",
    )
    sp.add_argument("--config", help="every [[board]] of the daemon's configuration, first")
    sp.add_argument("--out", required=True, help="directory to write the package into")
    sp.add_argument("--ros", type=int, choices=(1, 2), default=2, help="ROS version (2)")
    sp.add_argument("--package", default="missing_link_msgs", help="package name")
    add_timeout(sp)
    sp.add_argument(
        "--force", action="store_true", help="replace a package directory create-msgs did not write"
    )
    sp.add_argument(
        "--fresh",
        action="store_true",
        help="start the package over: drop the types an earlier run wrote for other boards",
    )
    sp.add_argument(
        "--build",
        metavar="PREFIX",
        help="build the ROS 2 package with the ROS 2 in this environment and install it there",
    )


class _PublisherArg(argparse.Action):
    """``-p NAME`` (repeatable); its help lists the publishers this environment has, found only
    when the help is shown (finding them costs a look at the installed packages)."""

    def __init__(self, option_strings: list[str], dest: str, **kw: Any) -> None:
        super().__init__(option_strings, dest, metavar="NAME", **kw)

    @property
    def help(self) -> str:
        from ..publishers.registry import available_publishers

        return f"add a publisher ({', '.join(available_publishers())} here)"

    @help.setter
    def help(self, value: str | None) -> None:
        pass  # (argparse sets it; the property above answers)

    def __call__(self, parser: Any, namespace: Any, values: Any, option: Any = None) -> None:
        setattr(namespace, self.dest, [*(getattr(namespace, self.dest, None) or []), values])


def _run(sp: Parser) -> None:
    sp.add_argument("url", nargs="*", help="board URLs (added to those in --config)")
    sp.add_argument(
        "--config",
        help="TOML configuration (`missing-link examples DIR` writes missing-link.toml, every "
        "key explained)",
    )
    sp.add_argument("--publisher", "-p", action=_PublisherArg)
    sp.add_argument("--record", metavar="DIR", help="record everything to rosbag2/MCAP under DIR")
    sp.add_argument(
        "--foxglove",
        nargs="?",
        type=port_arg,
        const=8765,
        metavar="PORT",
        help="live view for Foxglove on ws://127.0.0.1:PORT (8765)",
    )
    sp.add_argument(
        "--web",
        nargs="?",
        const="127.0.0.1:8080",
        metavar="ADDR:PORT",
        help="the device console in a browser at http://ADDR:PORT/ (127.0.0.1:8080; another "
        "address needs TLS and a token in [web] of --config: docs/web.md)",
    )
    sp.add_argument(
        "--duration", type=seconds_arg, default=0, help="stop after S seconds (0 = run)"
    )
    sp.add_argument(
        "--wait-up",
        type=seconds_arg,
        default=0,
        metavar="S",
        help="fail (exit 1) unless every board is up within S seconds",
    )
    sp.add_argument("--view", action="store_true", help="a live view of boards and topics")
    sp.add_argument(
        "--auto",
        action="store_true",
        help="find J2A boards as they plug in ([discover] in --config): by default only USB "
        "devices known to be J2A boards are probed (docs/hardware.md)",
    )
    sp.add_argument(
        "--usb-id",
        action="append",
        metavar="VID:PID",
        help="--auto probes ports with this USB id (hex, PID may be *; repeatable), instead of "
        "the known J2A boards' (e.g. 2341:* for Arduinos running our firmware)",
    )
    sp.add_argument(
        "--listen",
        metavar="URL",
        help="accept boards that dial in (board file link {'kind': 'tcp', 'dial': 'ADDR:PORT'}): "
        "tcp://127.0.0.1:PORT, or signed+tcp://ADDR:PORT?key=FILE off loopback (docs/signing.md)",
    )
    sp.add_argument(
        "--accept",
        choices=("any", "known"),
        help="which boards that dial in are taken: any (default), or known: those whose board.id "
        "a [boards.NAME] id of --config names",
    )
    sp.add_argument("--port", action="append", metavar="GLOB", help="--auto looks at these devices")
    sp.add_argument("--serial", metavar="GLOB", help="--auto: only this USB serial number")
    sp.add_argument(
        "--any-usb",
        action="store_true",
        help="--auto probes every USB serial port (writes J2A bytes to whatever is there)",
    )


def _recover(sp: Parser) -> None:
    sp.add_argument("path", help="bag directory or .mcap file")
    sp.add_argument("--out", help="new bag directory (default: PATH_recovered)")


def _router(sp: Parser) -> None:
    sp.add_argument(
        "--listen", action="append", help="endpoint, e.g. tcp/0.0.0.0:7447 (repeatable)"
    )
    sp.add_argument("--connect", action="append", help="another router to join (repeatable)")
    sp.add_argument(
        "--config",
        help="a native Zenoh config (JSON5: TLS certificates, access_control; docs/security.md); "
        "--listen/--connect still apply",
    )


def _demo(sp: Parser) -> None:
    sp.add_argument("--duration", type=seconds_arg, default=20.0, help="seconds to run (20)")
    sp.add_argument(
        "--web",
        default="127.0.0.1:8080",
        metavar="ADDR:PORT",
        help="the device console at http://ADDR:PORT/ (127.0.0.1:8080; another free port if "
        "that one is taken; 'off': none)",
    )
    sp.add_argument("--record", default="recordings", help="recording directory (recordings)")
    sp.add_argument("--seed", type=int, default=0)


def _replay_rate(text: str) -> float:
    value = positive(text)
    if not 0.01 <= value <= 1000:
        raise argparse.ArgumentTypeError(f"{text}: the rate goes from 0.01 to 1000")
    return value


def _replay_listen(text: str) -> str:
    if text in ("pty", "pty://") or text.startswith("tcp://"):
        return text
    raise argparse.ArgumentTypeError(f"{text!r}: listen on pty or tcp://HOST:PORT")


def _replay(sp: Parser) -> None:
    sp.add_argument("recording", nargs="+", help="bag directories or .mcap files, in order")
    sp.add_argument("--rate", type=_replay_rate, default=1.0, help="times as fast as recorded (1)")
    sp.add_argument("--loop", action="store_true", help="start again after the end (a reset)")
    sp.add_argument(
        "--listen", type=_replay_listen, default="pty", help="pty (default) or tcp://127.0.0.1:0"
    )
    sp.add_argument("--board", action="append", metavar="NAME", help="only this board (repeatable)")
    sp.add_argument(
        "--lead",
        type=positive,
        default=1.0,
        metavar="S",
        help="the recording starts S s after a host's first request (1): time to sync",
    )


COMMANDS = (
    Command("info", "functions, properties and transducers of a board", "talk:cmd_info", _info),
    Command("call", "call a board function by name", "talk:cmd_call", _call),
    Command("listen", "print decoded samples live, one line each", "talk:cmd_listen", _listen),
    Command("sync", "clock synchronisation with a board, live", "talk:cmd_sync", _sync),
    Command(
        "config",
        "a board's run-time configuration: print, set (KEY=VALUE ...), save, reset",
        "configure:cmd_config",
        _config,
        "Print a board's configuration (one key = value per line), or set keys: all of them "
        "or none.  TARGET is a board URL, or the name of a board a running daemon holds (the "
        "daemon is asked then, never fought for the port).",
    ),
    Command(
        "create-msgs",
        "write .msg files and a ROS package from boards' descriptors",
        "msgs:cmd_create_msgs",
        _create_msgs,
    ),
    Command("run", "the daemon: every board's transducers as topics", "run:cmd_run", _run),
    Command("recover", "salvage a recording whose process died", "run:cmd_recover", _recover),
    Command(
        "flash",
        "put the firmware for a board file on a board",
        "deploy:cmd_flash",
        board_args.flash,
    ),
    Command(
        "update", "update a board's firmware over its link", "update:cmd_update", board_args.update
    ),
    Command(
        "key", "signing keys for boards on a network link", "deploy:cmd_key_new", board_args.key
    ),
    Command(
        "gen-firmware",
        "C tables for an AVR board from its board file",
        "deploy:cmd_gen_firmware",
        board_args.gen_firmware,
    ),
    Command("board", "run a virtual board", "virtual:cmd_board", board_args.board),
    Command(
        "world",
        "push, turn, place, tilt a virtual board's robot by hand; block, fail its sensors",
        "world:cmd_world",
        board_args.world,
        "A hand on the world of a running `board --file ... --world-control URL` (docs/world.md): "
        "what it does is applied at the world's next batch of ticks (up to 100 ms on); the "
        "state printed is the world's as it was asked, before that.",
    ),
    Command(
        "replay",
        "play a recording back as the boards that made it",
        "replay:cmd_replay",
        _replay,
    ),
    Command(
        "relay",
        "a fault-injecting relay in front of a board (tests)",
        "virtual:cmd_relay",
        board_args.relay,
    ),
    Command(
        "router",
        "a Zenoh router for daemons and consumers on several hosts",
        "router:cmd_router",
        _router,
    ),
    Command("demo", "the thesis test rig on two virtual boards, recorded", "demo:cmd_demo", _demo),
    Command(
        "examples",
        "write the example board files and configuration into DIR",
        "examples:cmd_examples",
        board_args.examples,
        "The example board files (MicroPython and AVR), the daemon's configuration with every "
        "key explained, a descriptor file and a certificate script, as installed with "
        "missing-link: written into DIR to read, copy and edit.",
    ),
)
