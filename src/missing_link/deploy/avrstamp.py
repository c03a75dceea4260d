"""Stamp an AVR image with who the board is and what it runs (docs/hardware.md, "Identity").

The C firmware (firmware/avr/src/identity.c, board_gen.c) is built with two placeholders in
flash: ``identity_stamp`` (32 bytes) and the value of the ``fw.hash`` property (16 bytes).
Stamping, once per build (the Makefile: ``python -m missing_link.deploy.avrstamp IN OUT --id
ID [--force]``):

1. ``fw.hash`` = the first 16 hex digits of SHA-256 over the flash image as built (``avr-objcopy
   -O binary -R .eeprom``), placeholders in place: the same program gives the same hash, whatever
   id it is stamped with.  To check an image: put both placeholders back, hash it.
2. the hash goes over its placeholder, and the id record over the other (as the EEPROM will
   hold it: ``"MLID"``, length, text, zeros, forced 0/1, check; identity.c), in the ELF as it
   is: nothing moves, the sizes stay.

The board takes the stamped id into its EEPROM when the EEPROM has none, or always when forced
(``flash --id``); without ``--id`` a fresh random one is stamped (``avr-`` and 12 hex digits),
so every board that is flashed has an id, and a re-flash keeps the one it has.
"""

from __future__ import annotations

import argparse
import hashlib
import re
import secrets
import subprocess
import sys
import tempfile
from pathlib import Path

from ..errors import ConfigError
from .avrgen import FW_HASH_PLACEHOLDER

#: identity.c's placeholder, as the ELF holds it (with its NUL)
ID_PLACEHOLDER = b"@@missing-link-id-placeholder@@\0"
ID_MAX = 25  #: characters of a board.id on AVR (the EEPROM record's)
#: what a board.id may be on AVR: printable ASCII without spaces
AVR_ID = re.compile(r"[!-~]{1,25}\Z")


def new_id() -> str:
    return "avr-" + secrets.token_hex(6)


def check_id(board_id: str) -> str:
    if not AVR_ID.match(board_id):
        raise ConfigError(
            f"--id {board_id!r}: 1..{ID_MAX} printable ASCII characters without spaces"
        )
    return board_id


def image_of(elf: Path, objcopy: str = "avr-objcopy") -> bytes:
    """The flash image of ``elf`` (what avrdude writes)."""
    with tempfile.TemporaryDirectory(prefix="missing-link-stamp-") as tmp:
        out = Path(tmp) / "image.bin"
        subprocess.run(
            [objcopy, "-O", "binary", "-R", ".eeprom", str(elf), str(out)],
            check=True, capture_output=True, timeout=60,
        )  # fmt: skip
        return out.read_bytes()


def firmware_hash(image: bytes) -> str:
    return hashlib.sha256(image).hexdigest()[:16]


def id_record(board_id: str, force: bool) -> bytes:
    """The EEPROM record of ``board_id`` (identity.c): what the stamp holds."""
    raw = board_id.encode()
    body = b"MLID" + bytes((len(raw),)) + raw
    body += bytes(30 - len(body)) + bytes((1 if force else 0,))
    check = 0xA5
    for b in body:
        check ^= b
    return body + bytes((check,))


def _once(data: bytes, what: bytes, name: str, elf: Path) -> None:
    n = data.count(what)
    if n != 1:
        raise ConfigError(
            f"{elf}: {name} placeholder found {n} times (once expected): an image stamped "
            "already, or not built from firmware/avr"
        )


def stamp(unstamped: Path, out: Path, board_id: str | None, force: bool) -> tuple[str, str]:
    """Write the stamped copy of ``unstamped`` to ``out``; returns (fw.hash, board.id)."""
    data = unstamped.read_bytes()
    hash_text = FW_HASH_PLACEHOLDER.encode()
    _once(data, ID_PLACEHOLDER, "board.id", unstamped)
    _once(data, hash_text, "fw.hash", unstamped)
    fw_hash = firmware_hash(image_of(unstamped))
    ident = check_id(board_id) if board_id else new_id()
    data = data.replace(ID_PLACEHOLDER, id_record(ident, force))
    data = data.replace(hash_text, fw_hash.encode())
    out.write_bytes(data)
    return fw_hash, ident


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m missing_link.deploy.avrstamp")
    p.add_argument("command", choices=["stamp"])
    p.add_argument("unstamped", type=Path)
    p.add_argument("out", type=Path)
    p.add_argument("--id", default="", help="board.id (default: a fresh random one)")
    p.add_argument("--force", action="store_true", help="the board takes it whatever it has")
    args = p.parse_args(argv)
    try:
        fw_hash, ident = stamp(args.unstamped, args.out, args.id or None, args.force)
    except (ConfigError, OSError, subprocess.SubprocessError) as e:
        print(f"missing-link: error: {e}", file=sys.stderr)
        return 1
    how = "forced" if args.force else "taken by a board whose EEPROM has none"
    print(f"stamped: fw.hash {fw_hash}, board.id {ident} ({how})")
    return 0


if __name__ == "__main__":
    sys.exit(main())
