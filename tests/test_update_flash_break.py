"""``flash`` onto a board whose firmware runs: the firmware turns Ctrl-C off and stops only on
the break between frames (board/wire.py), which mpremote (1.29, its "\\r\\x03") does not send,
so flash sends it first (deploy/flash.py ``send_break``).  The board is the serial board harness
(tests/serial_board.py): real mpremote over a pty into MicroPython 1.27's own REPL and
filesystem, the firmware its flash holds running from power-on as main.py runs it."""

from __future__ import annotations

import os
import tty
from pathlib import Path

import pytest

from missing_link.deploy import flash as flash_mod
from missing_link.deploy.boardfile import load_board_file
from missing_link.deploy.check import FlashError
from missing_link.deploy.flash import flash, micropython_files
from missing_link.host.board import Board

from .serial_board import SerialBoard

pytestmark = [pytest.mark.slow, pytest.mark.micropython]

ROOT = Path(__file__).resolve().parent.parent
RIG = ROOT / "examples" / "boards" / "thesis-rig.py"


def _flashed_once(flash_dir: Path) -> None:
    board = SerialBoard(flash_dir)  # (an empty flash: the REPL is there, the break is harmless)
    try:
        assert flash(load_board_file(RIG), board.port, check=False, say=lambda s: None) == 0
        assert board.wait_gone(30) and board.was_reset
    finally:
        board.close()


def test_flash_stops_the_running_firmware_with_the_break(tmp_path: Path) -> None:
    flash_dir = tmp_path / "flash"
    _flashed_once(flash_dir)
    renamed = tmp_path / "rig2.py"
    renamed.write_text(RIG.read_text().replace('"name": "rig"', '"name": "rig2"'))
    board = SerialBoard(flash_dir)  # power on: main.py runs the firmware
    try:
        with Board.open(f"serial://{board.port}", timeout=3.0, describe=False) as b:
            assert b.properties["board.name"] == "rig"  # (J2A on the port, not the REPL)
        said: list[str] = []
        assert flash(load_board_file(renamed), board.port, check=False, say=said.append) == 0
        assert any("the running firmware stopped for the REPL" in s for s in said), said
        assert board.wait_gone(30) and board.was_reset
    finally:
        board.close()
    assert (flash_dir / "board.py").read_text() == renamed.read_text()
    for c in micropython_files(load_board_file(renamed)):
        assert (flash_dir / c.remote).read_bytes() == c.local.read_bytes(), c.remote


def test_without_the_break_mpremote_cannot_stop_it(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """What flash did before: mpremote alone meets a firmware that ignores its Ctrl-C (and,
    while the firmware sends, waits for ever: bounded here at 3 s)."""
    flash_dir = tmp_path / "flash"
    _flashed_once(flash_dir)
    before = {p: p.read_bytes() for p in flash_dir.rglob("*") if p.is_file()}
    monkeypatch.setattr(flash_mod, "send_break", lambda port: "repl")
    monkeypatch.setattr(flash_mod, "MPREMOTE_TIMEOUT_S", 3.0)
    renamed = tmp_path / "rig2.py"
    renamed.write_text(RIG.read_text().replace('"name": "rig"', '"name": "rig2"'))
    board = SerialBoard(flash_dir)
    try:
        with pytest.raises(FlashError, match="mpremote"):
            flash(load_board_file(renamed), board.port, check=False, say=lambda s: None)
    finally:
        board.close()
    assert {p: p.read_bytes() for p in flash_dir.rglob("*") if p.is_file()} == before


def test_a_board_that_never_says_it_stopped_is_an_error_before_mpremote(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A port where nothing answers the break (a firmware that does not listen, a wrong
    port): one clear error after the wait, and mpremote never runs."""
    master, slave = os.openpty()
    tty.setraw(slave)
    ran: list[list[str]] = []
    monkeypatch.setattr(flash_mod, "_run_mpremote", lambda cmd, port: ran.append(cmd))
    try:
        with pytest.raises(FlashError, match="did not stop") as e:
            flash(load_board_file(RIG), os.ttyname(slave), check=False, say=lambda s: None)
        assert os.read(master, 64) == flash_mod.BREAK  # (the break went out, nothing else)
    finally:
        os.close(master)
        os.close(slave)
    assert "\n" not in str(e.value) and "missing-link firmware stopped: REPL" in str(e.value)
    assert ran == []
