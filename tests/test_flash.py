"""Board files and ``missing-link flash``: what would be copied, the checks on the board file,
real mpremote at the port boundary, and the J2A check after flashing against the firmware
running under real MicroPython."""

from __future__ import annotations

import random
from pathlib import Path

import pytest

from missing_link.daemon.config import ConfigError
from missing_link.deploy.boardfile import load_board_file
from missing_link.deploy.check import FlashError, verify
from missing_link.deploy.flash import flash, micropython_files
from missing_link.errors import MissingLinkError
from missing_link.host.board import Board
from missing_link.transport import open_transport

from .helpers import FirmwareSim, ml
from .serial_board import SerialBoard

ROOT = Path(__file__).resolve().parent.parent
RIG = ROOT / "examples" / "boards" / "thesis-rig.py"


def board_file(tmp_path: Path, body: str) -> Path:
    p = tmp_path / "board.py"
    p.write_text(body)
    return p


SERVO_ONLY = """BOARD = {"name": "arm", "transducers": [
    {"name": "servo", "id": 3, "driver": "servo", "pin": 15}]}
"""


WIFI = ROOT / "examples" / "boards" / "esp32-wifi.py"


def _answers(url: str, key: Path) -> bool:
    try:  # (another key is named at the signed hello: docs/signing.md)
        transport = open_transport(f"signed+{url}?key={key}")
    except MissingLinkError as e:
        assert "key differs" in str(e), e
        return False
    board = Board(transport, timeout=3.0)
    try:
        board.handshake()
        return board.properties["board.name"] == "wifi"
    except MissingLinkError:
        return False
    finally:
        board.close()


@pytest.mark.slow
@pytest.mark.micropython
def test_the_key_reaches_the_board_and_a_new_key_replaces_the_old(tmp_path: Path) -> None:
    """``flash --key`` with the real mpremote on a serial port whose other end is MicroPython's
    own REPL and filesystem (tests/serial_board.py); the board's filesystem is read back after
    the reset, and the firmware booted from it (board file and key as flashed) answers the
    host that has the key, and not one with another key.  Flashed again with a new key (a leak),
    the old key stops working."""
    flash_dir = tmp_path / "flash"  # the board's flash, kept across power cycles
    keys = [tmp_path / "first.key", tmp_path / "after-a-leak.key"]
    for key in keys:
        key.write_text(random.randbytes(32).hex() + "\n")
    bf = load_board_file(WIFI)
    for key, other in ((keys[0], keys[1]), (keys[1], keys[0])):
        board = SerialBoard(flash_dir)
        said: list[str] = []
        try:
            assert flash(bf, board.port, key=str(key), say=said.append) == 0
            assert board.wait_gone(30) and board.was_reset  # (mpremote's `reset`)
        finally:
            board.close()
        on_board = {
            f.relative_to(flash_dir).as_posix(): f.read_bytes()
            for f in flash_dir.rglob("*")
            if f.is_file()
        }
        for c in micropython_files(bf, str(key)):  # every file, as it is here
            assert on_board.get(c.remote) == c.local.read_bytes(), c.remote
        assert on_board["mlkey.bin"] == key.read_bytes()
        assert any("network board" in line for line in said)
        sim = FirmwareSim(flash_dir / "board.py", files={"mlkey.bin": flash_dir / "mlkey.bin"})
        try:
            assert _answers(sim.url, key)
            assert not _answers(sim.url, other)
        finally:
            sim.close()


@pytest.mark.slow
def test_keys_go_where_the_board_reads_them(tmp_path: Path) -> None:
    key = tmp_path / "robot.key"
    key.write_text(random.randbytes(32).hex() + "\n")
    plain = tmp_path / "plain.py"  # a network board without a key: flashed, with a warning
    plain.write_text(WIFI.read_text().replace(', "key_file": "mlkey.bin"', ""))
    r = ml("flash", str(plain), "--dry-run")
    assert r.returncode == 0 and ":mlkey.bin" not in r.stdout, r.stderr
    assert r.stderr.startswith("missing-link: warning: ") and "unauthenticated" in r.stderr
    assert r.stderr.count("\n") == 1
    r = ml("flash", str(plain), "--dry-run", "--key", str(key))  # a key it would not read
    assert r.returncode == 1 and "the link has no key_file" in r.stderr, r.stderr
    r = ml("flash", str(WIFI), "--dry-run", "--key", str(key))
    assert r.returncode == 0 and not r.stderr, r.stderr
    assert f"fs cp {Path(r.stdout.split('fs cp -r ')[1].split()[0]).parent}/mlkey.bin" in r.stdout
    assert r.stdout.index(":mlkey.bin") < r.stdout.index(":main.py")  # main.py last


def test_only_the_drivers_the_board_uses_are_copied(tmp_path: Path) -> None:
    bf = load_board_file(board_file(tmp_path, SERVO_ONLY))
    remote = [c.remote for c in micropython_files(bf)]
    assert "lib/mlboard/drivers/servo.py" in remote
    assert not any(r.endswith(("srf02.py", "sharp.py", "mpu6050.py")) for r in remote)
    assert remote[-2:] == ["board.py", "main.py"]  # main.py last: the board boots only complete
    assert all(c.local.exists() for c in micropython_files(bf))


@pytest.mark.slow
def test_dry_run_lists_files_and_the_mpremote_command() -> None:
    r = ml("flash", str(RIG), "--port", "/dev/ttyACM7", "--dry-run")
    assert r.returncode == 0, r.stderr
    assert ":lib/mlboard/drivers/srf02.py" in r.stdout and ":board.py" in r.stdout
    assert "mpremote connect /dev/ttyACM7 fs cp -r" in r.stdout and "+ reset" in r.stdout


@pytest.mark.slow
@pytest.mark.parametrize(
    ("body", "message"),
    [
        ("BOARD = dict(name='x')", "BOARD must be a literal"),
        ("X = 1", "no `BOARD = {...}` dict"),
        ("BOARD = {'name': 'Front!', 'transducers': []}", "name must be a topic token"),
        (
            "BOARD = {'name': 'a', 'transducers': [{'name': 's', 'id': 1, 'driver': 'lidar'}]}",
            "driver 'lidar' is not one of",
        ),
        (
            "BOARD = {'name': 'a', 'transducers': [{'name': 's', 'id': 1, 'driver': 'servo'}]}",
            "driver servo needs 'pin'",
        ),
        (
            "BOARD = {'name': 'a', 'transducers': [{'name': 's', 'id': 1, 'driver': 'servo', "
            "'pin': 1, 'speed': 3}]}",
            "driver servo has no option 'speed'",
        ),
        (
            "BOARD = {'name': 'a', 'transducers': [{'name': 's', 'id': 1, 'driver': 'srf02', "
            "'bus': 'i2c1'}]}",
            "bus 'i2c1' is not in buses",
        ),
        ("BOARD = {", "not Python"),
    ],
)
def test_board_file_errors_are_one_line_exit_2(tmp_path: Path, body: str, message: str) -> None:
    p = board_file(tmp_path, body)
    with pytest.raises(ConfigError, match=message.replace("(", r"\(").replace("{", r"\{")):
        load_board_file(p)
    r = ml("flash", str(p), "--dry-run")
    assert r.returncode == 2 and r.stderr.count("\n") == 1 and message in r.stderr, r.stderr


@pytest.mark.slow
def test_a_missing_port_is_one_line_exit_1(tmp_path: Path) -> None:
    r = ml("flash", str(board_file(tmp_path, SERVO_ONLY)), "--port", str(tmp_path / "ttyACM9"))
    assert r.returncode == 1, r.stderr
    assert r.stderr.startswith("missing-link: error: cannot open ")
    assert r.stderr.count("\n") == 1 and "Traceback" not in r.stderr


@pytest.mark.slow
def test_verify_against_the_firmware_under_micropython(tmp_path: Path) -> None:
    sim = FirmwareSim(RIG)
    try:
        assert "rig answers J2A with 7 transducers" in verify(sim.url, load_board_file(RIG))
        other = board_file(tmp_path, RIG.read_text().replace('"name": "rig"', '"name": "rig2"'))
        with pytest.raises(FlashError, match="the board file says 'rig2'"):
            verify(sim.url, load_board_file(other))
    finally:
        sim.close()


UNO = ROOT / "examples" / "boards" / "thesis-rig-uno.py"


@pytest.mark.slow
def test_avr_dry_run_shows_the_build_and_avrdude() -> None:
    r = ml("flash", str(UNO), "--port", "/dev/ttyACM3", "--dry-run")
    assert r.returncode == 0, r.stderr
    assert "make -C" in r.stdout and "src/missing_link/firmware/avr BOARD=" in r.stdout
    assert "avrdude -p m328p -c arduino -P /dev/ttyACM3 -b 115200 -D -U flash:w:" in r.stdout


@pytest.mark.slow
@pytest.mark.avr
def test_avr_flash_builds_then_real_avrdude_fails_on_a_missing_port(tmp_path: Path) -> None:
    r = ml("flash", str(UNO), "--port", str(tmp_path / "ttyACM9"))
    assert "atmega328p: flash" in r.stdout  # built for real, size printed
    assert r.returncode == 1, r.stderr
    assert r.stderr.startswith("missing-link: error: avrdude on ")
    assert "cannot open port" in r.stderr
    assert r.stderr.count("\n") == 1 and "Traceback" not in r.stderr


@pytest.mark.slow
def test_avr_board_file_errors_name_the_fixed_pins(tmp_path: Path) -> None:
    from missing_link.deploy.avrgen import generate_avr

    def encoder_at(a: int, b: int) -> Path:
        text = UNO.read_text().replace('"pin_a": 2, "pin_b": 3', f'"pin_a": {a}, "pin_b": {b}')
        return board_file(tmp_path, text)

    assert "PCINT2_vect" in generate_avr(load_board_file(encoder_at(4, 5)))  # (pin-change)
    with pytest.raises(ConfigError, match=r"servo: pin \(OC1A\) 9 is wheel \(pin_b\)'s already"):
        generate_avr(load_board_file(encoder_at(2, 9)))
    said = r"wheel: pin_a: pin 0 has no interrupt on the Uno/Nano \(external: 2, 3; pin-change"
    with pytest.raises(ConfigError, match=said) as e:
        generate_avr(load_board_file(encoder_at(0, 1)))
    assert str(e.value).count(".py:") == 1, e.value  # (its prefix once)
    body = UNO.read_text().replace('"pin": 9,', '"pin": 10,')
    with pytest.raises(ConfigError, match=r"the servo is on pin 9 \(OC1A\)"):
        generate_avr(load_board_file(board_file(tmp_path, body)))
    r = ml("gen-firmware", str(RIG), "--out", str(tmp_path / "x"))
    assert r.returncode == 2 and "is not an AVR" in r.stderr
