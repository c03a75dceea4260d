"""``flash`` and ``gen-firmware`` refuse a board file whose firmware cannot fit its board, with
the numbers (deploy/heap.py for MicroPython, deploy/avrsize.py for AVR; docs/hardware.md,
"Memory"), and the heap table they use is what the simulator measures."""

from __future__ import annotations

import json
import re
import subprocess
import sys
from pathlib import Path

import pytest

from missing_link.deploy import heap
from missing_link.deploy.boardfile import load_board_file
from missing_link.virtual.mpyboard import find_micropython

ROOT = Path(__file__).resolve().parent.parent
EXAMPLES = ROOT / "examples" / "boards"
UNO = EXAMPLES / "thesis-rig-uno.py"
#: the thesis rig on an Uno and two motors, a stepper, an HC-SR04 and a battery more, without
#: run-time configuration (its keys would be more than the AVR runtime holds): under 384 bytes
#: left for the stack
UNO_AND_A_MOTOR = (
    UNO.read_text()
    .replace('"mcu": "atmega328p",', '"mcu": "atmega328p", "features": ["timing", "log"],')
    .replace(
        """         "call": "a2j_trigger"},
    ],""",
        """         "call": "a2j_trigger"},
        {"name": "motor", "id": 5, "driver": "hbridge", "pwm_pin": 6, "dir_pin": 7,
         "call": "a2j_motor"},
        {"name": "mast", "id": 6, "driver": "stepper", "step_pin": 8, "dir_pin": 12,
         "steps_per_rev": 200, "call": "a2j_mast"},
        {"name": "motor_b", "id": 7, "driver": "hbridge", "pwm_pin": 5, "dir_pin": 4,
         "call": "a2j_motor_b"},
        {"name": "front", "id": 8, "driver": "hcsr04", "trig_pin": 13, "echo_pin": 15},
        {"name": "pack", "id": 9, "driver": "battery", "pin": 2},
    ],""",
    )
)


def cli(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "missing_link", *args], capture_output=True, text=True, timeout=300
    )


def _imus(n: int) -> dict[str, object]:
    return {"name": "big", "mcu": "rp2040", "buses": {"i2c0": {"id": 0, "scl": 5, "sda": 4}},
            "transducers": [{"name": f"imu{i}", "id": i, "driver": "mpu6050", "bus": "i2c0"}
                            for i in range(n)]}  # fmt: skip


@pytest.mark.slow
def test_flash_refuses_a_micropython_board_file_too_big_for_its_heap(tmp_path: Path) -> None:
    big = tmp_path / "big.py"
    big.write_text("BOARD = " + json.dumps(_imus(60)) + "\n")
    r = cli("flash", str(big), "--port", "/dev/ttyACM0", "--dry-run")
    assert r.returncode == 2 and r.stderr.count("\n") == 1, r.stderr
    assert "does not fit the rp2040's heap" in r.stderr
    imus = f"60 x mpu6050 {60 * heap.INSTANCES['mpu6050'] / 1024:.1f} KiB"
    assert imus in r.stderr and "205 KiB free" in r.stderr, r.stderr
    assert "micropython/micropython#12557" in r.stderr  # (where the figure comes from)
    assert "would copy" not in r.stdout


@pytest.mark.parametrize("name", ["rover.py", "thesis-rig.py", "esp32-wifi.py"])
def test_the_example_boards_fit(name: str) -> None:
    bf = load_board_file(EXAMPLES / name)
    est = heap.check_fit(bf)
    assert est is not None and est.need <= heap.FREE_HEAP[bf.mcu].bytes
    assert est.parts[0][0] == "the firmware's runtime"  # (the biggest part of a small board)


def test_a_board_file_just_over_a_picos_heap_is_refused_and_just_under_is_not(
    tmp_path: Path,
) -> None:
    per = heap.INSTANCES["mpu6050"]
    room = heap.FREE_HEAP["rp2040"].bytes - (heap.RUNTIME + heap.WORKING + heap.BUS)
    fits = (room - heap.MODULES["mpu6050"]) // per
    for n, ok in ((fits, True), (fits + 1, False)):
        path = tmp_path / f"imus{n}.py"
        path.write_text("BOARD = " + json.dumps(_imus(n)) + "\n")
        bf = load_board_file(path)
        if ok:
            assert heap.check_fit(bf) is not None
        else:
            with pytest.raises(heap.DoesNotFit, match=f"{n} x mpu6050"):
                heap.check_fit(bf)


@pytest.mark.micropython
@pytest.mark.slow
def test_the_heap_table_is_what_the_simulator_measures() -> None:
    """deploy/heap.py's figures, measured again (virtual/world/heapprobe.mjs): each within 10 %
    or 256 bytes (a driver that grew means the table is due again: heap.measure)."""
    node, mpy = find_micropython()
    got = heap.measure(node, mpy)

    def near(table: int, measured: int) -> bool:
        return abs(table - measured) <= max(256, measured // 10)

    assert near(heap.RUNTIME, got["runtime"]), got["runtime"]
    for module, size in heap.MODULES.items():
        assert near(size, got["modules"][module]), (module, size, got["modules"][module])
    for driver, size in heap.INSTANCES.items():
        assert near(size, got["instance"][driver]), (driver, size, got["instance"][driver])
    assert set(heap.INSTANCES) == set(heap.PROBE_ENTRIES)


@pytest.mark.avr
@pytest.mark.slow
def test_gen_firmware_refuses_an_avr_board_file_too_big_with_the_numbers(tmp_path: Path) -> None:
    bf = tmp_path / "uno_motor.py"
    bf.write_text(UNO_AND_A_MOTOR)
    r = cli("gen-firmware", str(bf), "--out", str(tmp_path / "out"))
    assert r.returncode == 2 and r.stderr.count("\n") == 1, r.stderr
    said = re.search(
        r"does not fit the atmega328p: (?:flash (\d+) of 32256 bytes \(biggest code: .+\); )?"
        r"RAM (\d+) of 2048 bytes static leaves (\d+) for the stack, which needs 384 "
        r"\(biggest in RAM: parser \d+, tx_buf \d+",
        r.stderr,
    )
    assert said, r.stderr
    flash, ram, left = (int(g or 0) for g in said.groups())
    assert left == 2048 - ram and (flash > 32256 or left < 384)
    assert not (tmp_path / "out").exists()  # (refused: nothing written)
    ok = cli("gen-firmware", str(UNO), "--out", str(tmp_path / "uno"))
    assert ok.returncode == 0 and "atmega328p: flash" in ok.stdout, ok.stderr


@pytest.mark.avr
@pytest.mark.slow
def test_flash_refuses_an_avr_board_file_too_big_before_avrdude(tmp_path: Path) -> None:
    bf = tmp_path / "uno_motor.py"
    bf.write_text(UNO_AND_A_MOTOR)
    r = cli("flash", str(bf), "--port", str(tmp_path / "ttyACM9"))
    assert r.returncode == 2 and r.stderr.count("\n") == 1, r.stderr
    assert "does not fit the atmega328p" in r.stderr and "avrdude" not in r.stderr


@pytest.mark.slow
def test_update_refuses_a_micropython_board_file_too_big_before_it_connects(
    tmp_path: Path,
) -> None:
    big = tmp_path / "big.py"
    big.write_text("BOARD = " + json.dumps(_imus(60)) + "\n")
    r = cli("update", "tcp://127.0.0.1:9", str(big))  # (nothing listens there: not reached)
    assert r.returncode == 2 and r.stderr.count("\n") == 1, r.stderr
    assert "does not fit the rp2040's heap" in r.stderr
