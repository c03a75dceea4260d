"""The AVR image holds what its board file uses (issue 46.1): each driver's C only when an entry
names it, each feature (timing, config, log) only when the board file's `features` lists it;
``gen-firmware`` prints the flash by part, measured from the linked image's map."""

from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

import pytest

from missing_link.deploy.boardfile import load_board_file
from missing_link.errors import ConfigError

ROOT = Path(__file__).resolve().parent.parent
UNO = ROOT / "examples" / "boards" / "thesis-rig-uno.py"
ROW = re.compile(r"^  (.+?)\s+(\d+) B\s+[\d.]+ %", re.M)


def gen(board: Path, out: Path) -> tuple[int, dict[str, int]]:
    r = subprocess.run(
        [sys.executable, "-m", "missing_link", "gen-firmware", str(board), "--out", str(out)],
        capture_output=True, text=True, timeout=300,
    )  # fmt: skip
    assert r.returncode == 0, r.stderr
    flash = int(re.search(r"flash (\d+) of", r.stdout).group(1))  # type: ignore[union-attr]
    rows = {label: int(n) for label, n in ROW.findall(r.stdout)}
    return flash, rows


def variant(tmp: Path, features: list[str]) -> Path:
    text = UNO.read_text().replace(
        '"mcu": "atmega328p",', f'"mcu": "atmega328p", "features": {features!r},'
    )
    p = tmp / "uno.py"
    p.write_text(text)
    return p


@pytest.mark.avr
@pytest.mark.slow
def test_gen_firmware_prints_the_flash_by_part_and_the_parts_add_up(tmp_path: Path) -> None:
    flash, rows = gen(UNO, tmp_path / "out")
    assert rows.pop("image") == flash
    assert sum(rows.values()) == flash  # (measured from the map: nothing estimated, nothing lost)
    for part in ("driver quadrature", "driver servo", "driver sharp_gp2y0a02", "driver srf02",
                 "driver trigger", "runtime", "board tables (board_gen.c)"):  # fmt: skip
        assert rows[part] > 0, part
    assert all(rows[f] > 0 for f in rows if f.startswith("feature "))
    assert len([f for f in rows if f.startswith("feature ")]) == 3


@pytest.mark.avr
@pytest.mark.slow
def test_a_feature_the_board_file_leaves_out_is_not_in_its_image(tmp_path: Path) -> None:
    full, _ = gen(UNO, tmp_path / "full")
    small, rows = gen(variant(tmp_path, ["timing", "log"]), tmp_path / "small")
    assert not any(label.startswith("feature config") for label in rows)
    assert small < full * 0.85  # (the configuration is 4 KB of the rig's image)
    src = (tmp_path / "small" / "board_gen.c").read_text()
    assert "a2jConfigSet" not in src and "config_boot" not in src and "a2jAt" in src
    bare, rows = gen(variant(tmp_path, []), tmp_path / "bare")  # (the trigger without timing)
    assert not any(label.startswith("feature ") for label in rows) and bare < small


def test_features_are_checked(tmp_path: Path) -> None:
    with pytest.raises(ConfigError, match="'sign' is not one of timing, config, log"):
        load_board_file(variant(tmp_path, ["timing", "sign"]))
    pico = tmp_path / "pico.py"
    pico.write_text(
        'BOARD = {"name": "p", "mcu": "rp2040", "features": ["log"], "transducers": '
        '[{"name": "s", "id": 0, "driver": "servo", "pin": 2, "call": "a2j_s"}]}\n'
    )
    with pytest.raises(ConfigError, match="only an AVR image leaves features out"):
        load_board_file(pico)
    assert load_board_file(variant(tmp_path, [])).features == ()


def test_a_pin_error_says_its_prefix_once(tmp_path: Path) -> None:
    """Issue 46.6: "mybot_uno2.py: steer: mybot_uno2.py: steer: ..." no more."""
    from missing_link.deploy.avrgen import generate_avr

    p = tmp_path / "mybot_uno2.py"
    p.write_text(
        'BOARD = {"name": "u", "mcu": "atmega328p", "transducers": [{"name": "steer", "id": 0, '
        '"driver": "hbridge", "pwm_pin": 6, "dir_pin": 99, "call": "a2j_steer"}]}\n'
    )
    with pytest.raises(ConfigError) as e:
        generate_avr(load_board_file(p))
    assert str(e.value).count("steer:") == 1 and str(e.value).count("mybot_uno2.py") == 1, e.value


#: an H-bridge, a stepper and an HC-SR04 on an Uno (issue 46: "no longer fits" at bb0fb70)
MOTOR_UNO = """BOARD = {"name": "uno_motor", "mcu": "atmega328p", "buses": {"twi": {"id": 0}},
"transducers": [
    {"name": "motor", "id": 0, "driver": "hbridge", "pwm_pin": 6, "dir_pin": 7,
     "call": "a2j_motor"},
    {"name": "mast", "id": 1, "driver": "stepper", "step_pin": 8, "dir_pin": 12,
     "steps_per_rev": 200, "call": "a2j_mast"},
    {"name": "sonar", "id": 2, "driver": "hcsr04", "trig_pin": 4, "echo_pin": 15},%s
]}
"""
#: ... and one driver more: an SRF02 (the biggest driver with its TWI master)
ONE_MORE = """
    {"name": "front", "id": 3, "driver": "srf02", "bus": "twi", "address": 0x70},"""


@pytest.mark.avr
@pytest.mark.slow
def test_the_thesis_rig_takes_at_most_80_percent_of_an_uno(tmp_path: Path) -> None:
    flash, _ = gen(UNO, tmp_path / "out")
    assert flash <= 0.8 * 32256, flash


@pytest.mark.avr
@pytest.mark.slow
def test_a_motor_a_stepper_and_a_sonar_fit_an_uno_with_room_for_one_more_driver(
    tmp_path: Path,
) -> None:
    board = tmp_path / "uno_motor.py"
    board.write_text(MOTOR_UNO % "")
    flash, rows = gen(board, tmp_path / "out")
    assert {"driver hbridge", "driver stepper", "driver hcsr04"} <= set(rows)
    board.write_text(MOTOR_UNO % ONE_MORE)
    more, rows = gen(board, tmp_path / "more")  # (gen-firmware refuses what does not fit)
    assert "driver srf02" in rows and flash < more <= 32256
