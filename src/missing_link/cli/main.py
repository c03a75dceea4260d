"""The ``missing-link`` command: the parser built from the table of commands (commands.py),
the command's own module imported when it runs, and every error one line on stderr with its
exit code: 0 ok, 1 the board, the link or a publisher failed, 2 bad command line or input,
130 interrupted.

Start-up is most of a one-off command's time, so only what the command uses is imported: a
``missing-link call`` loads the J2A client and the daemon's control client, and nothing of the
daemon's service, numpy, zenoh or rich (tests/test_startup.py holds it to that)."""

from __future__ import annotations

import argparse
import contextlib
import functools
import importlib
import os
import sys
from collections.abc import Sequence
from typing import Any, NoReturn

from ..errors import BadURL, ConfigError, DescriptorError, MissingLinkError
from ..logs import install as install_log
from ..version import __version__
from .commands import COMMANDS
from .common import EXIT_FAIL, EXIT_INTERRUPTED, EXIT_USAGE, error

NAMES = frozenset(c.name for c in COMMANDS)


class _Parser(argparse.ArgumentParser):
    """A usage error is one line too (argparse would print the usage first)."""

    def __init__(self, **kw: Any) -> None:
        super().__init__(formatter_class=_Formatter, **kw)

    def error(self, message: str) -> NoReturn:
        self.exit(EXIT_USAGE, f"missing-link: error: {message} (see {self.prog} --help)\n")


class _Formatter(argparse.HelpFormatter):
    """argparse's, its width found once and without shutil: argparse makes a formatter for
    every argument it adds, and importing shutil (with bz2 and lzma) took 2 ms of a one-off call."""

    def __init__(
        self,
        prog: str,
        indent_increment: int = 2,
        max_help_position: int = 24,
        width: int | None = None,
    ) -> None:
        width = _columns() - 2 if width is None else width
        super().__init__(prog, indent_increment, max_help_position, width)


@functools.cache
def _columns() -> int:
    """The terminal's width as shutil.get_terminal_size finds it: $COLUMNS, stdout's, 80."""
    with contextlib.suppress(KeyError, ValueError):
        if (columns := int(os.environ["COLUMNS"])) > 0:
            return columns
    try:
        return os.get_terminal_size(sys.__stdout__.fileno()).columns or 80  # type: ignore[union-attr]
    except (AttributeError, ValueError, OSError):
        return 80


def build_parser(command: str | None = None) -> argparse.ArgumentParser:
    """Every command's parser; with ``command``, only that one's (all a command line naming
    it needs: building every command's arguments costs more than parsing them)."""
    p = _Parser(
        prog="missing-link",
        description="Sensor boards on a J2A link: inspect, call, listen, simulate.",
        epilog="Board URLs: tcp://HOST:PORT, unix:///PATH, serial:///dev/ttyACM0?baud=115200, "
        "usb://[BUS:ADDR][?serial=S], memory://NAME; prefix spy+ to hex-dump the traffic.",
    )
    p.add_argument("--version", action="version", version=f"missing-link {__version__}")
    sub = p.add_subparsers(dest="command", required=True, metavar="COMMAND")
    for c in COMMANDS:
        if command is None or c.name == command:
            sp = sub.add_parser(c.name, help=c.help, description=c.description)
            c.arguments(sp)
            sp.set_defaults(func=c.handler)
    return p


def main(argv: Sequence[str] | None = None) -> int:
    words = list(sys.argv[1:] if argv is None else argv)
    args = build_parser(words[0] if words and words[0] in NAMES else None).parse_args(words)
    # the daemon's warnings (a board that is not up, a name taken) as plain lines on stderr,
    # and every library's: made safe and rate-limited, they may carry what a board or a
    # network client sent (logs.py)
    install_log(sys.stderr)
    module, _, name = str(args.func).partition(":")
    try:
        run = getattr(importlib.import_module(f"{__package__}.{module}"), name)
        return int(run(args))
    except (BadURL, DescriptorError, ConfigError) as e:
        return error(f"{e}{_examples_hint(args)}", EXIT_USAGE)
    except MissingLinkError as e:
        return error(e, EXIT_FAIL)
    except ModuleNotFoundError as e:
        extra = _extra_of(str(e.name or "").split(".")[0])
        if extra is None:
            raise  # (not a library an extra brings: a bug, with its traceback)
        print(f"missing-link: error: {args.command} needs {e.name}, which is not installed here "
              f"(pip install 'missing-link[{extra}]')", file=sys.stderr)  # fmt: skip
        return EXIT_USAGE
    except KeyboardInterrupt:
        return EXIT_INTERRUPTED
    except BrokenPipeError:
        return 0


def _extra_of(module: str) -> str | None:
    """The package's extra (pyproject's optional dependencies) that brings ``module``: a
    requirement named as it (websockets, mpremote) or ending in -module (eclipse-zenoh,
    ros-kilted-rclpy), as the installed metadata says; None when none does."""
    import re
    from importlib.metadata import PackageNotFoundError, requires

    try:
        wanted = requires("missing-link") or []
    except PackageNotFoundError:
        return None
    for req in wanted:
        got = re.match(r"([A-Za-z0-9._-]+).*;\s*extra\s*==\s*['\"]([\w-]+)['\"]", req)
        if got and got.group(2) != "dev":
            dist = got.group(1).lower().replace("_", "-")
            if module and (dist == module.lower() or dist.endswith("-" + module.lower())):
                return got.group(2)
    return None


#: the arguments that name input files (a board file, a configuration, descriptors, recordings)
FILE_ARGS = ("boardfile", "file", "config", "source", "recording", "path")


def _examples_hint(args: argparse.Namespace) -> str:
    """A file the command was given that is not there but is an installed example: where it is
    (examples.py); "" otherwise."""
    paths: list[str] = []
    for key in FILE_ARGS:
        value = getattr(args, key, None)
        paths += [str(v) for v in value] if isinstance(value, list) else [value] if value else []
    if not paths:
        return ""
    from .examples import hint

    return hint(paths)


if __name__ == "__main__":
    sys.exit(main())
