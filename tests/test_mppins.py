"""A MicroPython board file's pins are checked against its MCU (issue 45.5): an encoder and a
servo both on GP2, a Sharp ranger on pin 99 passed ``board --file`` and ``flash --dry-run``.
Now each is one line naming the transducer, the key and the pin, exit 2, in ``board --file``,
``flash``, ``gen-firmware`` and ``update`` (deploy/mppins.py has the datasheets' tables)."""

from __future__ import annotations

import copy
import logging
from pathlib import Path
from typing import Any

import pytest

from missing_link.cli.main import main
from missing_link.deploy.boardfile import check_board, load_board_file
from missing_link.errors import ConfigError

ROOT = Path(__file__).resolve().parent.parent

SHARED = """BOARD = {
    "name": "mybot", "mcu": "rp2040",
    "transducers": [
        {"name": "wheel", "id": 0, "driver": "quadrature", "pin_a": 2, "pin_b": 3},
        {"name": "steer", "id": 1, "driver": "servo", "pin": 2, "call": "a2j_steer"},
    ],
}
"""
PIN_99 = """BOARD = {
    "name": "mybot", "mcu": "rp2040",
    "transducers": [{"name": "dist_ir", "id": 0, "driver": "sharp_gp2y0a02", "pin": 99}],
}
"""


@pytest.mark.parametrize(
    "argv",
    [
        ["board", "--file", "F", "--listen", "pty"],
        ["flash", "F", "--dry-run"],
        ["gen-firmware", "F", "--out", "fw"],
        ["update", "tcp://127.0.0.1:9", "F"],
    ],
)
@pytest.mark.parametrize(
    ("text", "said"),
    [
        (SHARED, "mybot.py: steer: pin 2: GPIO 2 is wheel's pin_a already"),
        (PIN_99, "mybot.py: dist_ir: pin 99: the rp2040 has no GPIO 99 (GPIO 0..29)"),
    ],
)
def test_every_command_refuses_a_pin_in_one_line(
    argv: list[str],
    text: str,
    said: str,
    tmp_path: Path,
    monkeypatch: pytest.MonkeyPatch,
    capsys: pytest.CaptureFixture[str],
) -> None:
    (tmp_path / "mybot.py").write_text(text)
    monkeypatch.chdir(tmp_path)
    assert main([a if a != "F" else "mybot.py" for a in argv]) == 2
    assert capsys.readouterr().err == f"missing-link: error: {said}\n"


def board(mcu: str, *entries: dict[str, Any], **more: Any) -> dict[str, Any]:
    out = {"name": "b", "mcu": mcu, "transducers": [{"id": k, **e} for k, e in enumerate(entries)]}
    return {**out, **more}


def refused(b: dict[str, Any]) -> str:
    with pytest.raises(ConfigError) as e:
        check_board(b, "b.py")
    return str(e.value)


SERVO = {"name": "servo", "driver": "servo", "pin": 13, "call": "a2j_servo"}
WHEEL = {"name": "wheel", "driver": "quadrature", "pin_a": 18, "pin_b": 19}
IR = {"name": "ir", "driver": "sharp_gp2y0a02", "pin": 26}
WIFI = {"kind": "tcp", "port": 5000, "key_file": "k.bin"}


@pytest.mark.parametrize(
    ("b", "said"),
    [
        (board("esp32", {**SERVO, "pin": 34}), "servo: pin 34: GPIO 34 is input only (no output)"),
        (board("esp32", {**WHEEL, "pin_b": 35}), "pin_b 35: GPIO 35 is input only (no pull-up: "),
        (board("esp32", {**SERVO, "pin": 7}), "GPIO 7 is wired to the module's flash"),
        (board("esp32", {**SERVO, "pin": 20}), "the esp32 has no GPIO 20 (GPIO 0..19, 21..23, "),
        (board("esp32", {**IR, "pin": 23}), "ir: pin 23: GPIO 23 has no ADC (the esp32's: GPIO"),
        (board("esp32", IR, link=WIFI), "GPIO 26 is on ADC2, which Wi-Fi takes (a tcp link): an "
         "ADC1 pin (GPIO 32..39)"),
        (board("esp32", {"name": "bump", "driver": "digital", "pin": 1}), "bump: pin 1: GPIO 1 is "
         "the usb link's (UART0 TX, the USB bridge's) already"),
        (board("esp32s3", {**SERVO, "pin": 30}), "GPIO 30 is wired to the module's flash"),
        (board("esp32s3", {**IR, "pin": 21}), "GPIO 21 has no ADC (the esp32s3's: GPIO 1..20)"),
        (board("rp2040", {"name": "imu", "driver": "mpu6050", "bus": "i2c0"},
               buses={"i2c0": {"id": 0, "scl": 4, "sda": 5}}),
         "b.py: bus i2c0 scl 4: I2C0 SCL is on GPIO 1, 5, 9, 13, 17, 21, 25, 29"),
        (board("rp2040", {"name": "gps", "driver": "gps_nmea", "uart": 1, "tx": 0, "rx": 1}),
         "gps: uart tx 0: UART1 TX is on GPIO 4, 8, 20, 24"),
        (board("rp2040", {**SERVO, "pin": 0}, {"name": "m", "driver": "hbridge", "pwm_pin": 1,
                                                "dir_pin": 2, "call": "a2j_m"}),
         "m: pwm_pin 1: PWM slice 0 (GPIO 0/1 and 16/17) runs at 50 Hz for servo: pin, not "
         "20000 Hz: a slice has one frequency"),
        (board("rp2040", {**SERVO, "pin": 0}, {**SERVO, "name": "pan", "pin": 16, "call": "a2j_p"}),
         "pan: pin 16: PWM slice 0 A is GPIO 0's output already (servo: pin): one signal"),
        (board("rp2040", {"name": "bump", "driver": "digital", "pin": 1},
               link={"kind": "uart", "id": 0, "tx": 0, "rx": 1}),
         "bump: pin 1: GPIO 1 is the link rx already"),
        (board("rp2040", IR, link={"kind": "uart", "id": 0, "tx": 0, "rx": 26}),
         "b.py: link rx 26: UART0 RX is on GPIO 1, 13, 17, 29"),
    ],
)  # fmt: skip
def test_a_pin_the_mcu_cannot_give_is_refused(b: dict[str, Any], said: str) -> None:
    assert said in refused(b)


def test_what_the_parts_can_have_passes() -> None:
    check_board(board("esp32", {**WHEEL, "pin_b": 35, "pull": "none"}, {**IR, "pin": 34}),
                "b.py")  # fmt: skip
    check_board(board("esp32", IR), "b.py")  # (ADC2 without Wi-Fi)
    check_board(board("rp2040", SERVO, {**SERVO, "name": "pan", "pin": 12, "call": "a2j_p"}),
                "b.py")  # (slices 6 B and 6 A: one frequency)  # fmt: skip
    for f in [*sorted((ROOT / "examples" / "boards").glob("*.py")),
              *sorted((ROOT / "tests" / "boards").glob("*.py"))]:  # fmt: skip
        load_board_file(f)


def test_a_strapping_pin_is_a_warning(caplog: pytest.LogCaptureFixture) -> None:
    with caplog.at_level(logging.WARNING):
        check_board(board("esp32", {**SERVO, "pin": 12}), "b.py")
    assert [r.getMessage() for r in caplog.records] == [
        "b.py: servo: pin 12: GPIO 12 is a strapping pin (MTDI: high at reset selects 1.8 V "
        "flash, and most modules do not boot)"
    ]


def test_a_refusal_changes_nothing_of_the_board() -> None:
    b = board("rp2040", SERVO)
    before = copy.deepcopy(b)
    check_board(b, "b.py")
    assert b == before
