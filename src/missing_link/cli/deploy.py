"""``flash`` and ``gen-firmware``: firmware from a board file onto a board."""

from __future__ import annotations

import argparse
from typing import Any


def cmd_flash(args: argparse.Namespace) -> int:
    from ..deploy.boardfile import load_board_file
    from ..deploy.flash import flash

    bf = load_board_file(args.boardfile)
    return flash(bf, args.port, dry_run=args.dry_run, check=not args.no_check, key=args.key)


def cmd_key_new(args: argparse.Namespace) -> int:
    """A new signing key (docs/signing.md): 32 random bytes as 64 hex digits, mode 0600."""
    import os
    import secrets
    import sys
    from pathlib import Path

    path = Path(args.file)
    if path.exists() and not args.force:
        print(f"missing-link: error: {path} exists (--force replaces it)", file=sys.stderr)
        return 2
    fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o600)
    with os.fdopen(fd, "w") as f:
        f.write(secrets.token_hex(32) + "\n")
    os.chmod(path, 0o600)
    print(f"wrote {path}: put it on the board over USB (flash --key) and give it to the host "
          f"(signed+tcp://HOST:PORT?key={path})")  # fmt: skip
    return 0


def cmd_gen_firmware(args: argparse.Namespace) -> int:
    from pathlib import Path

    from ..deploy.avrgen import write_avr
    from ..deploy.boardfile import load_board_file

    bf = load_board_file(args.boardfile)
    for path in write_avr(bf, Path(args.out)):
        print(f"wrote {path}")
    return 0


def add_parsers(sub: Any) -> None:
    sp = sub.add_parser("flash", help="put the firmware for a board file on a board")
    sp.add_argument("boardfile", help="board file (BOARD = {...}, see examples/boards/)")
    sp.add_argument("--port", default="/dev/ttyACM0", help="serial port (/dev/ttyACM0)")
    sp.add_argument("--dry-run", action="store_true", help="list files and commands, touch nothing")
    sp.add_argument(
        "--no-check", action="store_true", help="do not check the board answers J2A afterwards"
    )
    sp.add_argument(
        "--key",
        help="a signing key (missing-link key new) for a board on a network link: copied over "
        "USB as the board file's link key_file, never over the network (docs/signing.md)",
    )
    sp.set_defaults(func=cmd_flash)

    sp = sub.add_parser("key", help="signing keys for boards on a network link")
    ksub = sp.add_subparsers(dest="key_command", required=True, metavar="ACTION")
    kp = ksub.add_parser("new", help="write a new random key (mode 0600)")
    kp.add_argument("file")
    kp.add_argument("--force", action="store_true", help="replace an existing file")
    kp.set_defaults(func=cmd_key_new)

    sp = sub.add_parser("gen-firmware", help="C tables for an AVR board from its board file")
    sp.add_argument("boardfile", help="board file with mcu = atmega328p, atmega2560 or atmega32u4")
    sp.add_argument("--target", choices=["avr"], default="avr", help="firmware target (avr)")
    sp.add_argument("--out", required=True, help="directory for board_gen.c and board.mk")
    sp.set_defaults(func=cmd_gen_firmware)
