"""Run-time configuration of the AVR firmware as real AVR machine code in simavr: the same keys
as the MicroPython firmware makes from the same board file, a new rate at the simulated SRF02,
a disabled transducer sending nothing, the record in EEPROM across power cycles, and power cuts
in the middle of a save (the old configuration or the new one at the next boot, never a broken
one)."""

from __future__ import annotations

import struct
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import pytest

from missing_link.errors import MissingLinkError
from missing_link.host.board import Board
from missing_link.host.config import ConfigRefused
from missing_link.transport import open_transport

from .helpers import AvrSim, FirmwareSim, wait_for

ROOT = Path(__file__).resolve().parent.parent
UNO = ROOT / "examples" / "boards" / "thesis-rig-uno.py"
pytestmark = [pytest.mark.avr, pytest.mark.slow]


@contextmanager
def rig(build: Path, eeprom: Path) -> Iterator[tuple[AvrSim, Board]]:
    """The Uno rig powered on with its host handshaken; powered off at the end (its EEPROM
    written), or, when the test failed, stopped whatever state it is in: never left running."""
    sim = AvrSim(build, build / "uno_rig" / "firmware.elf", eeprom=eeprom)
    # (a bound on a call: a rig behind the host's time answers late, and one whose power was
    # cut has exited, its link gone at once)
    sim.timeout = 20.0
    try:
        yield sim, sim.host()
        sim.power_off()  # (a rig that cut its own power has exited: nothing to write)
    finally:
        sim.close()


def rangings(sim: AvrSim, seconds: float) -> tuple[int, float]:
    """The SRF02's rangings over at least ``seconds`` of simulated time, and that time (the
    rig's own count and clock, read together: a rig behind the host's time is not short)."""

    def stats() -> tuple[float, int]:
        f = sim.ctl("stats").split()
        return int(f[f.index("sim_us") + 1]) / 1e6, int(f[f.index("rangings") + 1])

    t0, n0 = stats()
    assert wait_for(lambda: stats()[0] - t0 >= seconds, 60)
    t1, n1 = stats()
    return n1 - n0, t1 - t0


@pytest.mark.micropython
def test_the_same_keys_as_the_micropython_firmware(avr_build: Path, tmp_path: Path) -> None:
    """gen-firmware makes the key table from the board file and the drivers' CONFIG: byte for
    byte what the MicroPython firmware serves for the same board file."""
    with rig(avr_build, tmp_path / "ee.bin") as (_sim, board):
        avr_keys = board.read_many("a2jConfigKeys")
        set_index = board.index["a2jConfigSet"]
        assert board.config()["sonar.units"] == "cm"
    mpy = FirmwareSim(UNO)
    try:
        b = Board(open_transport(mpy.url), timeout=5.0)
        try:
            b.handshake()
            assert b.read_many("a2jConfigKeys") == avr_keys
            assert b.index["a2jConfigSet"] == set_index
        finally:
            b.close()
    finally:
        mpy.close()


def test_configuration_on_avr_machine_code(avr_build: Path, tmp_path: Path) -> None:
    with rig(avr_build, tmp_path / "ee.bin") as (sim, board):
        assert board.config()["sonar.rate_hz"] == 10.0
        # the SRF02 pings at the new rate (the firmware's own timer decides)
        for rate in (2, 10):
            board.configure({"sonar.rate_hz": rate})
            n, span = rangings(sim, 2.0)
            assert rate * span - 1.5 <= n <= rate * span + 1, (rate, n, span)
        # disabled: no SIF of that transducer at all
        seen: list[int] = []
        board.on_sif(None, lambda sif, now: seen.append(sif.cmd))
        board.configure({"dist_ir.enabled": False})
        seen.clear()
        # two wheel SIFs (id 0) from later turns than the configure: every older SIF is here
        assert wait_for(lambda: seen.count(0) >= 2, 10)
        seen.clear()
        assert wait_for(lambda: seen.count(0) >= 25, 10)  # the wheel (id 0): 0.5 s of the board's
        assert 1 not in seen  # dist_ir (id 1, 25 Hz) silent meanwhile
        board.configure({"dist_ir.enabled": True})
        assert wait_for(lambda: 1 in seen, 5)
        # the servo: limits clamp the pulse; a combination it cannot take changes nothing
        assert board.call("a2j_set_servo", struct.pack("<b", 127)).code == 0
        board.configure({"servo.max_us": 1800})
        # (the pulse the simulated rig measures on the pin: the next servo period's)
        assert wait_for(lambda: sim.ctl("pulse").split()[1] == "1800.0", 10), sim.ctl("pulse")
        with pytest.raises(ConfigRefused, match="servo: need min_us < centre_us < max_us"):
            board.configure({"servo.max_us": 1400, "sonar.rate_hz": 3})
        assert board.config()["sonar.rate_hz"] == 10.0
        # what the host would never send, the board refuses itself (Python's texts)
        units = board.settings.by_name()["sonar.units"].index
        got = board.call("a2jConfigSet", bytes((0, units)) + struct.pack("<i", 0))
        assert (got.code, got.payload) == (0xFF, b"sonar.units: read-only")
        rate = board.settings.by_name()["sonar.rate_hz"].index
        got = board.call("a2jConfigSet", bytes((0, rate)) + struct.pack("<f", 99.0))
        assert (got.code, got.payload) == (0xFF, b"sonar.rate_hz: expected 0.1..15.38")
        got = board.call("a2jConfigSet", b"")
        assert got.code == 0xFF and got.payload.startswith(b"expects [flags]")
        board.configure({"servo.enabled": False})
        result = board.call("a2j_set_servo", struct.pack("<b", 10))
        assert result.code == 0xFF and result.payload == b"servo is disabled"


def test_a_saved_configuration_survives_power_and_cuts_leave_old_or_new(
    avr_build: Path, tmp_path: Path
) -> None:
    ee = tmp_path / "ee.bin"
    with rig(avr_build, ee) as (_sim, board):
        board.configure({"sonar.rate_hz": 5, "wheel.reverse": True}, save=True)
    with rig(avr_build, ee) as (_sim, board):
        got = board.config()
        assert got["sonar.rate_hz"] == 5.0 and got["wheel.reverse"] is True
        assert board.settings.state & 3 == 3  # saved, loaded at boot
    # a slot is 1 + 9 + 4 * 15 = 70 bytes; what changes in a save is a part of that
    for n in (1, 2, 8, 20, 40):
        with rig(avr_build, ee) as (sim, board):
            assert sim.ctl(f"cut {n}") == "ok"
            try:
                board.configure({"sonar.rate_hz": 7, "dist_ir.rate_hz": 11}, save=True)
                cut = False  # the save wrote fewer than n bytes: it completed
            except MissingLinkError:
                cut = True  # the power went in the middle of the save
            if cut:
                assert sim.lines.get(timeout=10) == "CUT"
                sim.proc.wait(10)  # (it stops at once: gone before its power-off)
        with rig(avr_build, ee) as (_sim, board):
            got = board.config()
            old = (got["sonar.rate_hz"], got["dist_ir.rate_hz"]) == (5.0, 25.0)
            new = (got["sonar.rate_hz"], got["dist_ir.rate_hz"]) == (7.0, 11.0)
            assert old or new, (n, got)
            assert new == (not cut), (n, cut, got)
            assert board.settings.state & 3 == 3
            board.configure({"sonar.rate_hz": 5, "dist_ir.rate_hz": 25}, save=True)  # again
