"""Firmware updates over the link, the parts that run anywhere: the boot record and which slot
starts (board/boot.py), the image and its staging into a slot (board/update.py, host/update.py)
on the board runtime under CPython, and what the host refuses before a byte of the image is
sent.  The whole update under the real MicroPython: tests/test_update_mpy.py; power cuts:
tests/test_update_powercut.py; AVR: tests/test_update_avr.py."""

from __future__ import annotations

import hashlib
import os
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import pytest

from missing_link.board import boot
from missing_link.board.boot import Boot, BootRecord, encode_record, parse_record, select
from missing_link.board.identity import tree_hash
from missing_link.board.runtime import BoardRuntime
from missing_link.board.update import ImageWriter, UpdateReceiver, check_path
from missing_link.deploy.boardfile import load_board_file
from missing_link.deploy.flash import firmware_hash, micropython_files
from missing_link.deploy.update import micropython_image, target_of
from missing_link.host.board import Board
from missing_link.host.update import (
    Target,
    UpdateFailed,
    Updater,
    UpdateRefused,
    check,
    image_of,
    parse_image,
    read_info,
)

ROOT = Path(__file__).resolve().parent.parent
ROVER = ROOT / "examples" / "boards" / "rover.py"
MODEL = "pico-rover"


@pytest.fixture
def flash(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Path:
    """The board's filesystem: the current directory, as on a board."""
    monkeypatch.chdir(tmp_path)
    return tmp_path


def _slot(flash: Path, slot: str) -> None:
    """A whole firmware in the slot (what select() requires to run it)."""
    d = flash / boot.slot_dir(slot)
    (d / "lib" / "mlboard").mkdir(parents=True, exist_ok=True)
    (d / "lib" / "mlboard" / "firmware.py").write_text("x = 1\n")
    (d / "board.py").write_text("BOARD = {}\n")


# ---- the boot record and which slot starts -----------------------------------------------------
def test_a_record_reads_back_and_a_torn_one_does_not(flash: Path) -> None:
    rec = {"seq": "3", "active": "a", "previous": "flash", "state": "trial", "tries": "0",
           "trial_s": "30", "hash": "0" * 16, "rolled": "", "why": "new\nline"}  # fmt: skip
    data = encode_record(rec)
    got = parse_record(data)
    assert got is not None and got["active"] == "a" and got["why"] == "new line"
    for n in range(len(data)):  # every length short of whole: not a record
        assert parse_record(data[:n]) is None, n
    flipped = bytearray(data)
    flipped[data.index(b"trial")] ^= 1
    assert parse_record(bytes(flipped)) is None


def test_writes_alternate_so_a_cut_write_leaves_the_record_before(flash: Path) -> None:
    store = BootRecord()
    assert store.read() is None
    store.write({"active": "a", "previous": "flash", "state": "trial", "tries": "0",
                 "trial_s": "30", "hash": "1" * 16, "rolled": "", "why": ""})  # fmt: skip
    first = (flash / "fw" / "boot.0").read_bytes()
    store.write({**(store.read() or {}), "tries": "1"})
    assert (flash / "fw" / "boot.0").read_bytes() == first  # the second went to boot.1
    (flash / "fw" / "boot.1").write_bytes((flash / "fw" / "boot.1").read_bytes()[:40])  # torn
    rec = store.read()
    assert rec is not None and rec["seq"] == "1" and rec["tries"] == "0"


def test_a_trial_starts_once_then_goes_back_with_its_reason(flash: Path) -> None:
    _slot(flash, "a")
    assert select().slot == "flash"  # no record: what flash put in the root
    BootRecord().write({"active": "a", "previous": "flash", "state": "trial", "tries": "0",
                        "trial_s": "20", "hash": "2" * 16, "rolled": "", "why": ""})  # fmt: skip
    first = select()
    assert (first.slot, first.trial, first.trial_s) == ("a", True, 20)
    assert boot.crashed(first, RuntimeError("boom"))
    back = select()
    assert (back.slot, back.trial, back.rolled) == ("flash", False, "a")
    assert "raised RuntimeError: boom" in back.note
    rec = BootRecord().read()
    assert rec is not None and (rec["active"], rec["state"], rec["rolled"]) == ("flash", "ok", "a")
    assert select().slot == "flash" and not select().note  # (said once)


def test_a_confirmed_trial_stays_and_a_missing_slot_is_not_run(flash: Path) -> None:
    _slot(flash, "b")
    BootRecord().write({"active": "b", "previous": "flash", "state": "trial", "tries": "0",
                        "trial_s": "20", "hash": "2" * 16, "rolled": "", "why": ""})  # fmt: skip
    chosen = select()
    rt = BoardRuntime("u", MODEL, "s1", epoch="e")
    up = UpdateReceiver(rt, {"mcu": "rp2040"}, chosen)
    assert up._confirm(b"") == (0, b"confirmed")
    assert select().slot == "b" and not select().trial
    BootRecord().write({"active": "a", "previous": "b", "state": "trial", "tries": "0",
                        "trial_s": "20", "hash": "2" * 16, "rolled": "", "why": ""})  # fmt: skip
    chosen = select()  # slot a holds nothing: the one before runs
    assert chosen.slot == "b" and chosen.rolled == "a" and "no whole firmware" in chosen.note


def test_a_trial_not_confirmed_in_time_asks_for_a_restart(flash: Path) -> None:
    _slot(flash, "a")
    BootRecord().write({"active": "a", "previous": "flash", "state": "trial", "tries": "0",
                        "trial_s": "5", "hash": "2" * 16, "rolled": "", "why": ""})  # fmt: skip
    now = [1_000_000]
    rt = BoardRuntime("u", MODEL, "s1", epoch="e", clock=lambda: now[0])
    up = UpdateReceiver(rt, {"mcu": "rp2040"}, select())
    assert up.due(now[0] + 4_999_999) is None
    why = up.due(now[0] + 5_000_000)
    assert why and "not confirmed" in why
    back = select()
    assert back.slot == "flash" and "no host confirmed it within 5 s" in back.note


# ---- the image, staged into a slot -----------------------------------------------------------
def _rover_files() -> list[tuple[str, bytes]]:
    return [(f.remote, f.local.read_bytes()) for f in micropython_files(load_board_file(ROVER))
            if f.remote.startswith("lib/") or f.remote == "board.py"]  # fmt: skip


def test_the_image_packs_what_flash_copies_and_hashes_as_the_board_will() -> None:
    bf = load_board_file(ROVER)
    img = micropython_image(bf)
    assert img.fw_hash == firmware_hash(micropython_files(bf))  # (the board file is in it)
    assert img.sha256 == hashlib.sha256(img.data).hexdigest()
    assert parse_image(img.data) == sorted(_rover_files())
    with pytest.raises(ValueError, match="a slot holds"):
        image_of([("main.py", b"x")])
    with pytest.raises(ValueError):
        parse_image(img.data[:-5])


@pytest.mark.parametrize(
    "path",
    [
        "main.py",
        "/lib/mlboard/x.py",
        "lib/mlboard/../../main.py",
        "lib/mlboard/x.mpy",
        "lib/other/x.py",
        "lib/mlboard/a b.py",
    ],
)
def test_a_slot_takes_the_runtime_and_the_board_file_only(path: str) -> None:
    with pytest.raises(ValueError, match="a slot does not take"):
        check_path(path)


def test_the_writer_takes_the_image_in_any_pieces(flash: Path) -> None:
    img = image_of(_rover_files())
    for size in (1, 7, 249, 4096):
        out = f"fw/s{size}/"
        w = ImageWriter(out, os, open)
        for i in range(0, len(img.data), size):
            w.feed(img.data[i : i + size])
        w.finish()
        assert tree_hash(out + "lib/mlboard", out + "board.py") == img.fw_hash


@pytest.fixture
def board(
    flash: Path, serve: Callable[..., Any]
) -> Iterator[tuple[Board, BoardRuntime, UpdateReceiver]]:
    """A runtime that takes updates, under CPython, on a memory link."""
    _slot(flash, "flash")
    rt = BoardRuntime("rover", MODEL, "s1", epoch="e")
    up = UpdateReceiver(rt, {"mcu": "rp2040"}, Boot("flash"))
    server = serve(rt)
    b = Board.open(server.url, timeout=2.0)
    try:
        yield b, rt, up
    finally:
        b.close()


def test_staged_files_are_checked_against_the_sha256_and_their_hash(
    board: tuple[Board, BoardRuntime, UpdateReceiver], flash: Path
) -> None:
    b, _rt, up = board
    img = image_of(_rover_files(), "0.3.0")
    info = read_info(b)
    assert (info["slot"], info["state"], info["mcu"]) == ("flash", "ok", "rp2040")
    updater = Updater(img, Target(MODEL, "rp2040"))
    assert updater._begin(b) == "a"
    updater._stage(b, ("0.2.0", "old"), 0.0)
    assert up.staged and tree_hash("fw/a/lib/mlboard", "fw/a/board.py") == img.fw_hash
    # an image whose bytes are not the ones begun with: refused at its end, said why
    bad = image_of(_rover_files())
    forged = type(bad)(bad.files, bad.data, "0" * 64, bad.fw_hash)
    updater = Updater(forged, Target(MODEL, "rp2040"))
    assert updater._begin(b) == "a"
    with pytest.raises(UpdateFailed, match=r"SHA-256 is not the one begun with.*nothing was sw"):
        updater._stage(b, ("0.2.0", "old"), 0.0)
    assert not up.staged and read_info(b)["error"].endswith("not the one begun with")


def test_what_is_refused_before_a_byte_is_sent(
    board: tuple[Board, BoardRuntime, UpdateReceiver],
) -> None:
    b, _rt, _up = board
    img = image_of(_rover_files())
    info = read_info(b)
    check(b, info, img, Target(MODEL, "rp2040", b.properties["board.id"]))  # (all well)
    cases = [
        (Target(MODEL, "rp2040", "somebody-else"), img, "not 'somebody-else' as named"),
        (Target("uno-thesis-rig", "rp2040"), img, "another kind of board"),
        (Target(MODEL, "esp32"), img, "made for mcu 'rp2040'"),
        (Target(MODEL, "rp2040"), image_of(_rover_files(), key_file="mlkey.bin"),
         "an unsigned update to a board that requires signing"),
    ]  # fmt: skip
    for target, image, why in cases:
        with pytest.raises(UpdateRefused, match=why):
            check(b, info, image, target)
    with pytest.raises(UpdateRefused, match="free for it"):
        check(b, {**info, "room": "1000"}, img, Target(MODEL, "rp2040"))
    with pytest.raises(UpdateRefused, match="on trial"):
        check(b, {**info, "state": "trial"}, img, Target(MODEL, "rp2040"))
    assert not Path("fw").exists()  # (nothing was begun)


def test_a_board_without_updates_is_refused_by_name(serve: Callable[..., Any]) -> None:
    b = Board.open(serve("thesis").url, timeout=2.0)
    try:
        with pytest.raises(UpdateRefused, match="takes no update over the link"):
            read_info(b)
    finally:
        b.close()


def test_the_target_is_the_board_files_identity() -> None:
    bf = load_board_file(ROVER)
    assert target_of(bf, None) == Target("pico-rover", "rp2040", "")
    assert target_of(bf, "e6605838").board_id == "e6605838"


def test_flash_copies_every_module_of_the_runtime() -> None:
    """Every module of board/ reaches a board (signing.py was left out: a board with a key
    flashed by `flash` could not start its link), main.py as the boot loader in the root."""
    from missing_link.deploy.flash import BOARD_PKG, RUNTIME

    assert {p.name for p in BOARD_PKG.glob("*.py")} - {"main.py"} == set(RUNTIME)
    remote = [c.remote for c in micropython_files(load_board_file(ROVER))]
    assert remote[-1] == "main.py" and "lib/mlboard/signing.py" in remote
