"""A simulated board's flash, a directory (``board --file F --runtime micropython --flash DIR``),
flashed as ``missing-link flash`` flashes a board: the runtime and the drivers F uses in
``lib/mlboard``, F as ``board.py``, ``main.py`` (the boot loader: board/main.py), the update
slots and their boot record (``fw/``) removed.  The simulator then starts from those files, as a
board does (virtual/world/flashboot.py), and takes updates (``missing-link update``).

A directory that holds the firmware for F already (the same files) is left as it is: what an
update put in ``fw/`` runs again at the next start, as on a board."""

from __future__ import annotations

import shutil
from collections.abc import Callable
from pathlib import Path

from .boardfile import BoardFile
from .flash import LIB, micropython_files

#: what flash and this leave out of the comparison: the board's own state
UPDATES = "fw"


def flashed(bf: BoardFile, flash: Path) -> bool:
    """Does ``flash`` hold what ``missing-link flash`` would put there for ``bf`` (no more
    runtime files, no fewer)?"""
    files = micropython_files(bf)
    for c in files:
        there = flash / c.remote
        if not there.is_file() or there.read_bytes() != c.local.read_bytes():
            return False
    lib = flash / LIB
    want = {c.remote for c in files if c.remote.startswith(LIB)}
    have = {p.relative_to(flash).as_posix() for p in lib.rglob("*.py")}
    return have == want


def install(bf: BoardFile, flash: Path) -> bool:
    """Flash ``bf`` onto ``flash`` unless it holds it already; True when it was flashed (what
    an update had put there is gone then, as after ``missing-link flash``)."""
    if flashed(bf, flash):
        return False
    shutil.rmtree(flash / UPDATES, ignore_errors=True)
    shutil.rmtree(flash / LIB, ignore_errors=True)
    for c in micropython_files(bf):
        dst = flash / c.remote
        dst.parent.mkdir(parents=True, exist_ok=True)
        shutil.copyfile(c.local, dst)
    return True


def prepare(board_file: Path, flash: Path, warn: Callable[[str], None]) -> None:
    """``board --file F --runtime micropython --flash DIR``: F's firmware onto DIR unless it is
    there already (an update kept), said when an update is forgotten."""
    from .boardfile import load_board_file

    had_update = (flash / UPDATES).is_dir()
    if install(load_board_file(board_file), flash) and had_update:
        warn(f"{flash} held another firmware: {board_file} flashed there, its update forgotten")
