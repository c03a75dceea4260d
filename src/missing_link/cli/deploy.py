"""``flash`` and ``gen-firmware``: firmware from a board file onto a board."""

from __future__ import annotations

import argparse
from typing import TYPE_CHECKING

from .common import EXIT_USAGE, error

if TYPE_CHECKING:
    from ..deploy.boardfile import BoardFile


def cmd_flash(args: argparse.Namespace) -> int:
    from ..deploy.boardfile import load_board_file
    from ..deploy.flash import flash

    bf = load_board_file(args.boardfile)
    return flash(bf, args.port, dry_run=args.dry_run, check=not args.no_check, key=args.key,
                 board_id=args.id)  # fmt: skip


def cmd_key_new(args: argparse.Namespace) -> int:
    """A new signing key (docs/signing.md): 32 random bytes as 64 hex digits, mode 0600."""
    import os
    import secrets
    from pathlib import Path

    path = Path(args.file)
    if path.exists() and not args.force:
        return error(f"{path} exists (--force replaces it)", EXIT_USAGE)
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
    if not args.no_fit_check:
        _check_fit(bf)
    for path in write_avr(bf, Path(args.out)):
        print(f"wrote {path}")
    return 0


def _check_fit(bf: BoardFile) -> None:
    """Build it in a scratch directory: a board file that cannot fit the MCU is refused (exit 2,
    the numbers), after what the tables alone say is wrong with it (write_avr's own errors)."""
    import shutil
    import sys
    import tempfile
    from pathlib import Path

    from ..deploy.avr import fit
    from ..deploy.avrgen import write_avr

    with tempfile.TemporaryDirectory(prefix="missing-link-gen-") as tmp:
        write_avr(bf, Path(tmp))
    if shutil.which("avr-gcc") is None:
        print(
            "missing-link: warning: cannot check that it fits the MCU: no avr-gcc (run "
            "scripts/system-deps.sh; --no-fit-check skips the check)",
            file=sys.stderr,
        )
        return
    size, table = fit(bf)
    print(size.line())
    print(f"flash by part (the linked image's map):\n{table}")
