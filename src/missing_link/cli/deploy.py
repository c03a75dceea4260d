"""``flash`` and ``gen-firmware``: firmware from a board file onto a board."""

from __future__ import annotations

import argparse
from typing import Any


def cmd_flash(args: argparse.Namespace) -> int:
    from ..deploy.boardfile import load_board_file
    from ..deploy.flash import flash

    bf = load_board_file(args.boardfile)
    return flash(bf, args.port, dry_run=args.dry_run, check=not args.no_check)


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
    sp.set_defaults(func=cmd_flash)

    sp = sub.add_parser("gen-firmware", help="C tables for an AVR board from its board file")
    sp.add_argument("boardfile", help="board file with mcu = atmega328p, atmega2560 or atmega32u4")
    sp.add_argument("--target", choices=["avr"], default="avr", help="firmware target (avr)")
    sp.add_argument("--out", required=True, help="directory for board_gen.c and board.mk")
    sp.set_defaults(func=cmd_gen_firmware)
