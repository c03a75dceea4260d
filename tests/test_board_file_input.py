"""Board files are input, not code: every name that reaches generated C, the J2A function
table, the descriptor or property text or the board's filesystem is checked by form, every value
by type, at the board file's boundary (one line, exit 2); the AVR generator refuses what is not
an identifier on its own too, so code in a board file never compiles into a firmware."""

from __future__ import annotations

import ast
import subprocess
import sys
from pathlib import Path

import pytest

from missing_link.deploy.avr import AVR_DIR
from missing_link.deploy.avrgen import generate_avr, write_avr
from missing_link.deploy.boardfile import BoardFile, load_board_file
from missing_link.errors import ConfigError

from .helpers import ml

ROOT = Path(__file__).resolve().parent.parent
UNO = ROOT / "examples" / "boards" / "thesis-rig-uno.py"
#: C that runs at boot (.init8 is kept by the linker and runs before main), closing the string
#: literal the generator put the call into, and opening another for the rest of the line
INJECTED = (
    'a2j_set_servo"; __attribute__((naked, used, section(".init8"))) void ml_injected(void) '
    '{ DDRB = 0xFF; } static const char ml_z[] PROGMEM = "x'
)


def write_board(tmp_path: Path, board: dict[str, object], name: str = "board.py") -> Path:
    p = tmp_path / name
    p.write_text(f"BOARD = {board!r}\n".replace(": inf", ": 1e999"))  # (a literal infinity)
    return p


def servo_board(**entry: object) -> dict[str, object]:
    servo = {"name": "servo", "id": 1, "driver": "servo", "pin": 15, **entry}
    return {"name": "arm", "transducers": [servo]}


SENSOR_WITH_CALL = {
    "name": "arm",
    "transducers": [{"name": "ir", "id": 0, "driver": "sharp_gp2y0a02", "pin": 26, "call": "go"}],
}
TWO_WITH_ONE_CALL = {
    "name": "arm",
    "transducers": [
        {"name": "a", "id": 0, "driver": "servo", "pin": 15, "call": "go"},
        {"name": "b", "id": 1, "driver": "servo", "pin": 16, "call": "go"},
    ],
}


@pytest.mark.slow
@pytest.mark.parametrize(
    ("board", "said"),
    [
        (servo_board(call=INJECTED), "call must be a function name"),
        (servo_board(call="a2jEcho"), "call must be a function name"),  # the firmware's own
        (servo_board(call="x" * 40), "call must be a function name"),
        (SENSOR_WITH_CALL, "only an actuator has a function to call"),
        (TWO_WITH_ONE_CALL, "call 'go' is used twice"),
        (servo_board(id=True), "id must be 0..239"),
        (servo_board(pin="15"), "servo: pin: expected an integer"),
        (servo_board(min_us="900; x"), "min_us: expected a number"),
        (servo_board(min_us=float("inf")), "min_us: expected a finite number"),
        (servo_board(safe="wobble"), "safe is one of 'hold', 'limp'"),
        (servo_board(failsafe_ms="500"), "failsafe_ms: expected an integer 0..60000"),
        (servo_board(prefix="servo,1,x"), "prefix: expected text"),
        (servo_board(model="HS\n645"), "model: expected text"),
        (servo_board(options={"frame_id": "arm\nfake,9,p,m,1,int8_t,0"}), "options frame_id"),
        (servo_board(options={"frame id": "arm"}), "is not a key like 'frame_id'"),
        ({**servo_board(), "model": "pico\0board.name\0evil"}, "model: expected text"),
        ({**servo_board(), "serail": "x"}, "unknown key 'serail'"),
        ({**servo_board(), "config_file": "../mlconfig.bin"}, "config_file: a file in the board"),
        (
            {**servo_board(), "link": {"kind": "tcp", "key_file": "../../.ssh/authorized_keys"}},
            "link key_file: a file in the board's root",
        ),
        ({**servo_board(), "link": {"kind": "tcp", "key_file": "main.py"}}, "not lib or a .py"),
        ({**servo_board(), "link": {"kind": "tcp", "port": "5000"}}, "link port: expected an"),
        ({**servo_board(), "link": {"kind": "usb", "port": 5000}}, "not a key of a usb link"),
        (
            {**servo_board(), "buses": {"i2c0": {"id": 0, "sda": 4, "scl": 5, "frq": 1}}},
            "unknown key 'frq'",
        ),
    ],
)
def test_a_wrong_board_file_is_one_line_exit_2(
    tmp_path: Path, board: dict[str, object], said: str
) -> None:
    p = write_board(tmp_path, board)
    with pytest.raises(ConfigError, match=None) as e:
        load_board_file(p)
    assert said in str(e.value) and str(p) in str(e.value)
    r = ml("flash", str(p), "--dry-run")
    assert r.returncode == 2 and r.stderr.count("\n") == 1, r.stderr
    assert said in r.stderr and "Traceback" not in r.stderr


@pytest.mark.slow
def test_a_board_file_that_is_no_file_is_refused_before_it_is_read(tmp_path: Path) -> None:
    big = tmp_path / "big.py"
    big.write_text("BOARD = {'name': 'a', 'transducers': []}\n" + "#" * (2 << 20))
    for path, said in (("/dev/zero", "not a regular file"), (str(big), "at most 1048576")):
        r = ml("flash", path, "--dry-run")
        assert r.returncode == 2 and said in r.stderr and r.stderr.count("\n") == 1, r.stderr


def test_the_generator_refuses_what_no_loader_checked(tmp_path: Path) -> None:
    """A dict handed to the generator directly (no board file loader in between): names that
    are not identifiers and values of the wrong type are ConfigErrors, not C and not tracebacks."""
    board = ast.literal_eval(UNO.read_text().split("BOARD = ", 1)[1])
    for k, e in enumerate(board["transducers"]):
        if e["driver"] == "servo":
            servo = k
    cases = [
        ({"call": INJECTED}, "is not a name the firmware can take"),
        ({"name": "servo */ int x; /*"}, "is not a name the firmware can take"),
        ({"min_us": "900); evil("}, "invalid literal for int()"),
        ({"pin": None}, "servo"),
    ]
    for change, said in cases:
        b = {**board, "transducers": list(board["transducers"])}
        b["transducers"][servo] = {**board["transducers"][servo], **change}
        with pytest.raises(ConfigError, match=None) as e:
            generate_avr(BoardFile(tmp_path / "raw.py", b))
        assert said in str(e.value)
    with pytest.raises(ConfigError, match="is not a name the firmware can take"):
        write_avr(BoardFile(tmp_path / "raw.py", {**board, "name": "x\nCC = evil"}), tmp_path)


@pytest.mark.slow
@pytest.mark.avr
def test_code_in_a_board_file_never_compiles_into_the_avr_firmware(tmp_path: Path) -> None:
    """The whole pipeline a user runs (make -C firmware/avr, which runs gen-firmware, then
    avr-gcc): a call that closes its string literal and defines code that runs at boot is
    refused with one line naming the entry and the key, and no firmware is built."""
    body = UNO.read_text()
    assert '"call": "a2j_set_servo"' in body
    p = tmp_path / "uno.py"
    p.write_text(body.replace('"call": "a2j_set_servo"', f'"call": {INJECTED!r}'))
    build = tmp_path / "build"
    make = ["make", "-C", str(AVR_DIR), f"BOARD={p}", f"BUILD={build}"]
    r = subprocess.run(
        [*make, f"PYTHON={sys.executable}"], capture_output=True, text=True, timeout=300
    )
    assert r.returncode != 0
    assert f"{p}: servo: call must be a function name" in r.stderr
    assert not list(build.rglob("firmware.elf")) and not list(build.rglob("board_gen.c"))
    assert "Traceback" not in r.stderr
