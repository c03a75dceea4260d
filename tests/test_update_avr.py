"""``missing-link update`` on AVR boards (deploy/update.py ``update_avr``): through the Arduino
bootloader with avrdude over the serial link, the daemon letting go of the port meanwhile and
taking it back after; over a network link refused with the reason before anything is sent.

Tested up to the bootloader's boundary: simavr runs the firmware (rig_sim), not an Arduino
bootloader, so the real avrdude meets the J2A firmware on the port and fails to get in sync;
what is checked is everything around it (the build, the daemon's release and retake, the one
line of avrdude's error, the board back up on its old firmware)."""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

import pytest

from missing_link.daemon import Config, Daemon
from missing_link.daemon.config import BoardSpec
from missing_link.virtual import make_sim, start_board_thread

from .helpers import AvrRig, ml, wait_for

ROOT = Path(__file__).resolve().parent.parent
UNO = ROOT / "examples" / "boards" / "thesis-rig-uno.py"


@pytest.mark.slow
def test_a_network_url_is_refused_before_anything_is_opened(tmp_path: Path) -> None:
    env = {**os.environ, "MISSING_LINK_CONTROL": str(tmp_path / "control.sock")}
    r = ml("update", "tcp://127.0.0.1:9", str(UNO), env=env)  # (nothing listens there)
    assert r.returncode == 1, r.stdout + r.stderr
    last = r.stderr.strip().splitlines()[-1]
    assert last.startswith("missing-link: error: ") and "a network link cannot reach" in last
    assert "Traceback" not in r.stderr


@pytest.mark.slow
def test_a_board_the_daemon_holds_over_a_network_link_is_refused(tmp_path: Path) -> None:
    """The daemon's board is on TCP: refused with the reason, no build, the board untouched."""
    board, thread = start_board_thread(make_sim("thesis", seed=3), "tcp://127.0.0.1:0")
    control = tmp_path / "control.sock"
    try:
        with Daemon(Config(boards=[BoardSpec(board.url)], control=str(control))) as d:
            assert d.wait_until_up(30), d.status()
            env = {**os.environ, "MISSING_LINK_CONTROL": str(control)}
            r = ml("update", "thesis", str(UNO), env=env)
            assert r.returncode == 1, r.stdout + r.stderr
            assert "a network link cannot reach the bootloader" in r.stderr, r.stderr
            assert "building" not in r.stderr
            st = {s["board"]: s for s in d.status()}
            assert st["thesis"]["connects"] == 1 and st["thesis"]["state"] == "up"
    finally:
        board.stop()
        thread.join(5)


@pytest.mark.slow
@pytest.mark.avr
def test_the_daemon_lets_go_of_the_port_for_avrdude_and_takes_it_back(
    tmp_path: Path, avr_rig: AvrRig
) -> None:
    rig = avr_rig("uno_rig")
    control = tmp_path / "control.sock"
    cfg = Config(boards=[BoardSpec(rig.url)], control=str(control))
    with Daemon(cfg) as d:
        assert d.wait_until_up(30), d.status()
        before = {s["board"]: s for s in d.status()}["uno_rig"]
        env = {**os.environ, "MISSING_LINK_CONTROL": str(control)}
        r = ml("update", "uno_rig", str(UNO), env=env, timeout=600)
        assert r.returncode == 1, r.stdout + r.stderr
        assert "atmega328p: flash" in r.stderr  # (built, its size line shown)
        last = r.stderr.strip().splitlines()[-1]
        port = rig.url.removeprefix("serial://")
        assert last.startswith(f"missing-link: error: avrdude on {port} failed: "), last
        assert "Traceback" not in r.stderr

        # the daemon let go of the port (a second connect) and has the board again, unchanged
        def rig() -> dict[str, Any]:
            return {s["board"]: s for s in d.status()}["uno_rig"]

        assert wait_for(lambda: (st := rig())["state"] == "up" and st["connects"] == 2, 30), rig()
        st = rig()
        assert st["fw_hash"] == before["fw_hash"]
        assert st["update"]["state"] == "port taken back", st["update"]


@pytest.mark.slow
@pytest.mark.avr
def test_an_update_that_cannot_fit_the_mcu_is_refused_before_avrdude(
    tmp_path: Path, avr_rig: AvrRig
) -> None:
    """Built and checked as `flash` and `gen-firmware` check it: over the Uno's flash or its
    stack's room is exit 2 with the numbers, and avrdude never runs (the build had its fit
    check off, and `update` made none)."""
    from .test_fit import UNO_AND_A_MOTOR

    rig = avr_rig("uno_rig")
    bf = tmp_path / "uno_motor.py"
    bf.write_text(UNO_AND_A_MOTOR)
    r = ml("update", rig.url, str(bf), timeout=600)
    assert r.returncode == 2, r.stdout + r.stderr
    last = r.stderr.strip().splitlines()[-1]
    assert "does not fit the atmega328p" in last and "avrdude" not in r.stderr, r.stderr
    assert "Traceback" not in r.stderr
