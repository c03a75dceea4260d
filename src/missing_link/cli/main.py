"""The ``missing-link`` command: each command group adds its own parsers; here they are
assembled and every error becomes one line on stderr with its exit code:
0 ok, 1 the board, the link or a publisher failed, 2 bad command line or input, 130 interrupted.

Only what a command uses is imported: the groups import their heavy parts inside the command,
so ``missing-link call`` loads the J2A client and nothing of the daemon, numpy or zenoh."""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence

from ..errors import BadURL, ConfigError, DescriptorError, MissingLinkError
from ..logs import install as install_log
from ..version import __version__
from . import configure, demo, deploy, msgs, replay, router, run, talk, virtual
from .common import EXIT_FAIL, EXIT_INTERRUPTED, EXIT_USAGE

GROUPS = (talk, configure, msgs, run, deploy, virtual, replay, router, demo)


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="missing-link",
        description="Sensor boards on a J2A link: inspect, call, listen, simulate.",
        epilog="Board URLs: tcp://HOST:PORT, unix:///PATH, serial:///dev/ttyACM0?baud=115200, "
        "usb://[BUS:ADDR][?serial=S], memory://NAME; prefix spy+ to hex-dump the traffic.",
    )
    p.add_argument("--version", action="version", version=f"missing-link {__version__}")
    sub = p.add_subparsers(dest="command", required=True, metavar="COMMAND")
    for group in GROUPS:
        group.add_parsers(sub)
    return p


def main(argv: Sequence[str] | None = None) -> int:
    # the daemon's warnings (a board that is not up, a name taken) as plain lines on stderr,
    # and every library's: made safe and rate-limited, they may carry what a board or a
    # network client sent (logs.py)
    install_log(sys.stderr)
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        return int(args.func(args))
    except (BadURL, DescriptorError, ConfigError) as e:
        print(f"missing-link: error: {e}", file=sys.stderr)
        return EXIT_USAGE
    except MissingLinkError as e:
        print(f"missing-link: error: {e}", file=sys.stderr)
        return EXIT_FAIL
    except KeyboardInterrupt:
        return EXIT_INTERRUPTED
    except BrokenPipeError:
        return 0


if __name__ == "__main__":
    sys.exit(main())
