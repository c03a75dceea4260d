"""The battery driver in the AVR C runtime (firmware/avr/src/battery.c) as real AVR machine code:
tests/boards/battery-uno.py built for an ATmega328P and, the same file with another mcu, an
ATmega2560, each run in simavr with a voltage on the divider's ADC input (rig_sim's ``ain``).
The pack voltage and charge it reports match the input within one ADC step, and the charge is
the Python driver's curve at that voltage; the daemon publishes them and a BatteryState; the key
table is byte for byte the MicroPython firmware's for the same board file."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path
from typing import Any

import pytest
from rosbags.typesys import Stores, get_typestore

from missing_link.board.drivers.battery import CURVES, charge
from missing_link.daemon import Daemon
from missing_link.daemon.config import BoardSpec, Config
from missing_link.deploy.avr import AVR_DIR as AVR
from missing_link.host.board import Board
from missing_link.topics import Update
from missing_link.transport import open_transport

from .helpers import AvrSim, FirmwareSim, wait_for

ROOT = Path(__file__).resolve().parent.parent
UNO = ROOT / "tests" / "boards" / "battery-uno.py"
STORE = get_typestore(Stores.ROS2_JAZZY)
RATIO = (10000.0 + 3300.0) / 3300.0  # the board file's divider
STEP = 5.0 / 1023 * RATIO  # one ADC code (AVcc = 5 V, 10 bits) at the pack
pytestmark = [pytest.mark.avr, pytest.mark.slow]


@pytest.fixture(scope="module")
def build(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The board file built for the Uno and (name and mcu changed) the Mega, and rig_sim."""
    out = tmp_path_factory.mktemp("avrbattery")
    mega = out / "battery-mega.py"
    text = UNO.read_text().replace('"atmega328p"', '"atmega2560"')
    mega.write_text(text.replace('"power_uno"', '"power_mega"'))
    for board, target in ((UNO, ["all", "sim"]), (mega, ["all"])):
        r = subprocess.run(
            ["make", "-C", str(AVR), f"BOARD={board}", f"BUILD={out}",
             f"PYTHON={sys.executable}", *target],
            capture_output=True, text=True, timeout=300,
        )  # fmt: skip
        assert r.returncode == 0, r.stdout + r.stderr
    return out


def mv_for(pack_volts: float) -> int:
    """The millivolts at the pin for a pack voltage (simavr takes whole mV)."""
    return round(pack_volts / RATIO * 1000)


@pytest.mark.parametrize(("name", "mcu"), [("power_uno", None), ("power_mega", "atmega2560")])
def test_voltage_and_charge_from_the_adc(build: Path, name: str, mcu: str | None) -> None:
    sim = AvrSim(build, build / name / "firmware.elf", mcu=mcu)
    try:
        _check_voltages(sim, name)
    finally:
        sim.close()


def _check_voltages(sim: AvrSim, name: str) -> None:
    thesis: list[Update] = []
    state: list[Update] = []
    with Daemon(Config(boards=[BoardSpec(sim.url, timeout=2.0, uart_baud=115200)])) as d:
        assert d.wait_until_up(20), d.status()
        d.subscribe(f"/{name}/battery", thesis.append, queue=0)
        d.subscribe(f"/{name}/battery/battery_state", state.append, queue=0)
        assert wait_for(lambda: thesis and thesis[-1].values == [None, None])  # 0 V: no pack
        for pack in (8.0, 7.4, 6.5, 8.4):  # 2S Li-ion: 4.0, 3.7, 3.25, 4.2 V a cell
            assert sim.ctl(f"ain 1 {mv_for(pack)}") == "ok"
            at_pin = mv_for(pack) / 1000 * RATIO  # what the input is, at the pack
            assert wait_for(lambda v=at_pin: close(thesis, v), 10), (pack, thesis[-1].values)
            volts, got = thesis[-1].values
            assert abs(volts - at_pin) <= STEP
            # the Python driver's curve at the voltage the board measured, and the input's
            assert got == pytest.approx(charge(CURVES["li-ion"], volts / 2), abs=1e-5)
            lo, hi = (charge(CURVES["li-ion"], (at_pin + s) / 2) for s in (-STEP, STEP))
            assert lo - 1e-6 <= got <= hi + 1e-6
            assert wait_for(lambda v=volts: state and battery(state[-1]).voltage == v, 5)
            b = battery(state[-1])
            assert b.percentage == pytest.approx(got, abs=1e-6)
            assert b.power_supply_technology == 2  # LION, from the board file's model
        # run-time keys: one cell, linear from 3.0 to 4.2 V (the board file's cell_empty/full)
        d.configure(name, {"battery.cells": 1, "battery.chemistry": "linear"})
        assert sim.ctl(f"ain 1 {mv_for(3.6)}") == "ok"
        assert wait_for(lambda: close(thesis, mv_for(3.6) / 1000 * RATIO), 10)
        volts, got = thesis[-1].values
        assert got == pytest.approx((volts - 3.0) / 1.2, abs=1e-5)
        assert sim.ctl("ain 1 0") == "ok"
        assert wait_for(lambda: thesis[-1].values == [None, None], 10)


def close(got: list[Update], volts: float) -> bool:
    return bool(got) and got[-1].values[0] is not None and abs(got[-1].values[0] - volts) <= STEP


def battery(u: Update) -> Any:
    return STORE.deserialize_cdr(u.cdr, u.topic.type_name)


@pytest.mark.micropython
def test_the_same_keys_as_the_micropython_firmware(build: Path) -> None:
    sim = AvrSim(build, build / "power_uno" / "firmware.elf")
    try:
        with Board(open_transport(sim.url), timeout=2.0) as board:
            board.handshake()
            avr_keys = board.read_many("a2jConfigKeys")
            assert board.config()["battery.ratio"] == pytest.approx(RATIO, rel=1e-6)
    finally:
        sim.close()
    mpy = FirmwareSim(UNO)
    try:
        with Board(open_transport(mpy.url), timeout=5.0) as b:
            b.handshake()
            assert b.read_many("a2jConfigKeys") == avr_keys
    finally:
        mpy.close()


def test_what_an_avr_cannot_do_is_refused(tmp_path: Path) -> None:
    bad = tmp_path / "bad.py"
    for change, why in (
        (('"pin": 1', '"pin": 9'), "pin is the ADC channel on AVR"),
        (('"vref": 5.0', '"vref": 6.0'), "vref is AVcc's voltage on AVR"),
        (('"cells": 2', '"cells": 2, "reads": 20'), "reads 1..9 on AVR"),
        (('"cells": 2', '"cells": 2, "cell_full": 2.9'), "cell_full > cell_empty > 0"),
        (('"r_bottom": 3300.0', '"r_bottom": 0.0'), "r_top >= 0 and r_bottom > 0"),
    ):
        bad.write_text(UNO.read_text().replace(*change))
        r = subprocess.run(
            [str(ROOT / ".venv" / "bin" / "missing-link"), "gen-firmware", str(bad),
             "--target", "avr", "--out", str(tmp_path / "out")],
            capture_output=True, text=True, timeout=60,
        )  # fmt: skip
        assert r.returncode != 0 and why in r.stderr, r.stderr
        assert len(r.stderr.strip().splitlines()) == 1 and "Traceback" not in r.stderr
