"""The rover's parts on AVR (examples/boards/rover-mega.py: the C runtime's hbridge.c,
stepper.c, hcsr04.c, gps_nmea.c, quadrature.c and failsafe.c) as real ATmega2560 machine code in
simavr, the parts modelled at the pins and the second UART (firmware/avr/sim/: motor.c turning
the wheels, stepper.c, hcsr04.c, gps.c, encoder.c); and gen-firmware refusing what an MCU cannot
do."""

from __future__ import annotations

import os
import signal
import struct
import subprocess
import time
from collections.abc import Callable, Iterator
from pathlib import Path

import pytest

from missing_link.daemon import Daemon
from missing_link.daemon.config import BoardSpec, Config
from missing_link.deploy.avrgen import generate_avr
from missing_link.deploy.boardfile import load_board_file
from missing_link.errors import ConfigError
from missing_link.host.board import Board
from missing_link.host.config import ConfigRefused
from missing_link.topics import Update
from missing_link.transport import open_transport

from .helpers import ML, AvrRig, AvrSim, FirmwareSim, ml, wait_for

ROOT = Path(__file__).resolve().parent.parent
pytestmark = pytest.mark.avr


@pytest.fixture
def rig(avr_rig: AvrRig) -> AvrSim:
    return avr_rig("mega_rover", rover=True)


@pytest.fixture
def rover(rig: AvrSim) -> Iterator[Daemon]:
    with Daemon(Config(boards=[BoardSpec(rig.url, timeout=2.0, uart_baud=115200)])) as d:
        assert d.wait_until_up(20), d.status()
        yield d


def listen(d: Daemon, name: str) -> list[Update]:
    got: list[Update] = []
    d.subscribe(f"/mega_rover/{name}", got.append, queue=0)
    return got


def motor(rig: AvrSim) -> tuple[float, int, float, int]:
    _, a, da, b, db = rig.ctl("motor").split()
    return float(a), int(da), float(b), int(db)


def utc_channels(utc: int) -> list[int]:
    """Channels 8 and 9 of the fix of UTC second ``utc``: its day since 1970, its ms of day."""
    return [utc // 86400, utc % 86400 * 1000]


def utc_second(u: Update) -> int:
    """The UTC second of a fix (channels 8 and 9), -1 when it has none."""
    day, ms = u.values[8:]
    return -1 if day is None else int(day) * 86400 + int(ms) // 1000


def rig_gps(rig: AvrSim) -> tuple[float, int]:
    """The rig's newest PPS edge: its board µs and its UTC second (firmware/avr/sim/rover.c)."""
    _, _, pps, utc = rig.ctl("gps").split()
    return float(pps), int(utc)


@pytest.mark.slow
def test_gps_on_the_second_uart_stamped_at_its_pps(rover: Daemon, rig: AvrSim) -> None:
    """Each fix is stamped at the PPS edge of its own second (INT4's entry) and carries that
    edge's UTC (channels 8 and 9, from RMC's date); bad checksums make no sample; no fix, no
    position and no UTC.  Every wait is on the simulation's own seconds (the UTC the rig sends,
    the UTC in each fix), never the host's: simavr runs slower than the host's time on a loaded
    machine, by how much nobody knows (the waits' ceilings only bound a stuck simulation)."""
    got = listen(rover, "gps")
    assert wait_for(lambda: len(got) >= 2, 30)
    lat, lon, alt, fix, sats, hdop, speed, course = got[-1].values[:8]
    assert (lat, lon, alt, fix, sats, hdop) == (481173000, 115166666, 545400, 1, 8, 90)
    assert (speed, course) == (22400 * 1852 // 3600, 8440)
    pps, utc = rig_gps(rig)
    n = len(got)
    assert wait_for(lambda: len(got) >= n + 3, 30)
    # The rig's edges come exactly 1 s apart (a cycle timer), so each fix is compared with the
    # edge of its own second.  Its stamp is INT4's entry: 1.875 µs after the edge in simavr, a
    # µs or two later when another interrupt (Timer1's overflow, the link's UART) ran at the
    # edge (measured: 31 x 1.875, 7 x 2.875, 2 x 3.875 µs over 40 edges with three threads
    # calling a2jEcho without a pause): so the best of them is the entry itself, and none is
    # near the '$' of its GGA (some 75 ms after the edge at 9600 baud), the stamp without PPS
    late = []
    for u in got:
        k = round((u.board_us[0] - pps) / 1e6)
        late.append(u.board_us[0] - pps - k * 1e6)
        assert 0 < late[-1] < 1000, (pps, u.board_us)
        assert u.values[8:] == utc_channels(utc + k), (utc, k, u.values)
        assert set(u.board_us) == {u.board_us[0]}  # every channel stamped at the edge
    assert min(late) <= 5.0, late
    # the date turns at midnight: 23:59:59 on 31 December 1999, then 00:00:00 on 1 January
    assert rig.ctl("gps utc 946684799") == "ok"
    new_year = utc_channels(946684800)
    assert wait_for(lambda: any(u.values[8:] == new_year for u in got), 30), got[-1].values
    k = next(i for i, u in enumerate(got) if u.values[8:] == new_year)
    assert [u.values[8:] for u in got[k - 1 : k + 1]] == [utc_channels(946684799), [10957, 0]]
    # Every GGA with a bad checksum: no sample.  The seconds the rig sends after the command
    # (its UTC then, first) are all bad until it is undone (last); the fix of the first good
    # second after it comes after any of theirs would have (one link, in order)
    rig.ctl("gps bad 2")
    _, first = rig_gps(rig)
    assert wait_for(lambda: rig_gps(rig)[1] >= first + 3, 30)
    rig.ctl("gps bad 0")
    _, last = rig_gps(rig)
    assert wait_for(lambda: any(utc_second(u) > last for u in got), 30)
    seen = {utc_second(u) for u in got}
    assert not seen & set(range(first + 1, last + 1)), (first, last, sorted(seen))
    n = len(got)
    rig.ctl("gps fix 0")
    assert wait_for(lambda: len(got) > n and got[-1].values[3] == 0, 30)
    assert got[-1].values[:3] == [None, None, None] and got[-1].values[8:] == [None, None]


@pytest.mark.slow
def test_hcsr04_echo_stamped_by_its_pin_change_interrupt(rover: Daemon, rig: AvrSim) -> None:
    got = listen(rover, "sonar")
    assert wait_for(lambda: len(got) >= 3, 5)
    assert got[-1].values[0] == pytest.approx(1000, abs=1)  # the echo's width at 20 degC
    assert rig.ctl("hcsr04 437") == "ok"
    assert wait_for(lambda: got[-1].values[0] == pytest.approx(437, abs=1), 5)
    assert rig.ctl("hcsr04 0") == "ok"  # nothing in range: the echo stays high 38 ms
    assert wait_for(lambda: got[-1].values == [None], 5)
    rover.configure("mega_rover", {"sonar.max_range_cm": 100, "sonar.rate_hz": 5})
    assert rig.ctl("hcsr04 1500") == "ok"  # beyond the configured range: N/A
    n = len(got)
    assert wait_for(lambda: len(got) >= n + 2 and got[-1].values == [None], 5)


def sim_wait(rig: AvrSim, cond: Callable[[], bool], board_s: float) -> bool:
    """Wait for ``cond`` up to ``board_s`` of the board's own time (the rig's simulated µs):
    simavr runs behind the host's time on a loaded machine, by how much nobody knows (seconds,
    measured), so a bound in the host's time can be hit by a correct run.  (The host's ceiling
    only bounds a stuck simulation.)"""
    end = rig.board_us() + board_s * 1e6
    wait_for(lambda: cond() or rig.board_us() >= end, 120)
    return cond()


@pytest.mark.slow
def test_motors_ramp_on_timer0_and_a_pwm_dir_bridge_cannot_brake(
    rover: Daemon, rig: AvrSim
) -> None:
    """The ramp, the duty on Timer0's outputs and the DIR pins.  The failsafe is disarmed here
    (failsafe_ms 0): its trips are the stepper test's and the goodbye test's, and in simavr a
    host that keeps the link alive can still trip it on a loaded machine (the rig's time is
    the host's clock caught up flat out after it fell behind, 3 times real time, while its pty
    thread waits for the CPU too: measured, a board 370 to 720 ms without a frame while the
    daemon sent one every 100 ms; a motor made safe mid-ramp never reported 0.5)."""
    rover.configure("mega_rover", {"motor_l.failsafe_ms": 0, "motor_r.failsafe_ms": 0})
    got = listen(rover, "motor_l")
    rover.send("/mega_rover/motor_l/cmd", 0.5)
    assert sim_wait(rig, lambda: bool(got) and got[-1].values == [0.5], 5), got[-1:]
    assert len(got) >= 5  # ramped (4 per second), each step reported
    assert abs(motor(rig)[0] - 0.5) < 0.01  # OCR0A = 128: (128 + 1) / 256 of each period
    rover.send("/mega_rover/motor_r/cmd", -0.25)  # (its bridge inverted: DIR low, forward)
    assert sim_wait(rig, lambda: abs(motor(rig)[2] - 0.25) < 0.01 and motor(rig)[3] == 0, 5)
    rover.send("/mega_rover/motor_l/cmd", -0.25)  # back: DIR high
    assert sim_wait(rig, lambda: abs(motor(rig)[0] - 0.25) < 0.01 and motor(rig)[1] == 1, 5)
    # a PWM/DIR bridge cannot brake: the board refuses it, naming why (config.c)
    with pytest.raises(ConfigRefused, match="stop = brake needs in1 and in2"):
        rover.configure("mega_rover", {"motor_l.stop": "brake"})


def wheels(rig: AvrSim) -> list[tuple[float, float]]:
    """Each wheel's (turns, turns/s) in the rig (firmware/avr/sim/motor.c)."""
    f = rig.ctl("wheels").split()[1:]
    return [(float(f[k + 1]), float(f[k + 2])) for k in range(0, len(f), 3)]


@pytest.mark.slow
def test_the_motors_turn_the_wheels_and_a_world_can_take_them_over(
    rover: Daemon, rig: AvrSim
) -> None:
    left, right = listen(rover, "wheel_l"), listen(rover, "wheel_r")
    rover.send("/mega_rover/motor_l/cmd", 0.5)
    rover.send("/mega_rover/motor_r/cmd", -0.5)  # (inverted bridge: forward; the count reversed)
    assert wait_for(lambda: left and left[-1].values[0] >= 400, 30)  # a turn: 400 edges
    assert wait_for(lambda: right and right[-1].values[0] <= -400, 30)  # this one goes back
    # (in each motor's own sense, half of the rig's top 2 turns/s: both forward, the right one
    # mounted mirrored, so that for the rover it goes back)
    (_turns_l, speed_l), (_turns_r, speed_r) = wheels(rig)
    assert speed_l == pytest.approx(1.0, abs=0.05) and speed_r == pytest.approx(1.0, abs=0.05)
    # the seam for a world: the rig's model lets go of a wheel, the world moves it
    assert rig.ctl("wheel 0 off") == "ok"
    time.sleep(0.2)
    n = left[-1].values[0]
    assert rig.ctl("enc 0 -1000") == "ok"
    assert wait_for(lambda: left[-1].values[0] == n - 1000, 5)
    time.sleep(0.3)  # (the motor still drives; the wheel is the world's now)
    assert left[-1].values[0] == n - 1000
    rover.send("/mega_rover/motor_l/cmd", 0.0)
    rover.send("/mega_rover/motor_r/cmd", 0.0)


@pytest.mark.slow
def test_stepper_counts_and_the_servo_goes_limp_when_the_host_is_gone(rig: AvrSim) -> None:
    """A host drives the stepper, the motors and the servo, then goes silent: after
    failsafe_ms (300 ms for the motors, 500 for the others) the motors coast, the stepper lets
    go and the servo (safe = limp) stops its pulses; a2jFailsafe and a2jDebug say so."""
    board = Board(open_transport(rig.url), timeout=5.0)
    try:
        board.handshake()

        def talking(cond: Callable[[], bool]) -> Callable[[], bool]:
            def check() -> bool:  # (the host talks meanwhile: no trip yet)
                board.call("a2jEcho")
                return cond()

            return check

        board.call_ok("a2j_mast", struct.pack("<f", 0.5))  # half a turn: 200 microsteps
        assert wait_for(talking(lambda: rig.ctl("stepper").split()[1] == "200"), 10)
        board.call_ok("a2j_mast", struct.pack("<f", 20.0))  # and on: still turning when ...
        board.call_ok("a2j_motor_l", struct.pack("<f", 1.0))
        board.call_ok("a2j_set_servo", struct.pack("<b", 40))
        assert wait_for(talking(lambda: motor(rig)[0] == 1.0), 5)
        assert rig.ctl("pulse").split()[1] != "0.0"
        rig.ctl("lag")  # (from here on)
        t0 = time.monotonic()  # ... the host goes quiet
        assert wait_for(lambda: motor(rig)[0] == 0.0, 5)
        # (not before 300 ms of the host's time, unless the rig fell behind it and caught up)
        assert time.monotonic() - t0 >= 0.25, f"tripped early; the rig's {rig.ctl('lag')}"
        assert wait_for(lambda: rig.ctl("stepper").split()[2] == "0", 5)  # enable off
        assert wait_for(lambda: rig.ctl("pulse").split()[1] == "0.0", 5)  # limp
        moved = rig.ctl("stepper").split()[1]
        time.sleep(0.3)
        assert rig.ctl("stepper").split()[1] == moved
        trips, age = struct.unpack("<II", board.call_ok("a2jFailsafe"))
        assert trips == 3 and age < 5000  # the three commanded: motor_l, the stepper, the servo
        assert board.call_ok("a2jDebug").decode().startswith("failsafe: motor_l safe (no frame")
    finally:
        board.close()


@pytest.mark.slow
def test_the_daemon_says_goodbye_and_a_killed_one_trips_the_failsafe(
    avr_build: Path, rig: AvrSim, tmp_path: Path
) -> None:
    cfg = tmp_path / "d.toml"
    cfg.write_text(
        f'[daemon]\npublishers = ["bus"]\ncontrol = "{tmp_path}/c.sock"\n'
        f'[[board]]\nurl = "{rig.url}"\nuart_baud = 115200\n'
    )
    env = {**os.environ, "MISSING_LINK_CONTROL": f"{tmp_path}/c.sock"}

    def drive() -> bool:  # through the daemon's control endpoint, as a user would
        r = ml("call", "mega_rover", "a2j_motor_r", "--value", "0.75", timeout=30, env=env)
        return r.returncode == 0

    for kill in (signal.SIGTERM, signal.SIGKILL):
        p = subprocess.Popen(
            [*ML, "run", "--config", str(cfg)],
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
        )
        try:
            assert wait_for(drive, 30)
            assert wait_for(lambda: abs(motor(rig)[2] - 0.75) < 0.01, 5)
            rig.ctl("lag")  # (from here on)
            time.sleep(1.0)  # the daemon keeps the quiet link alive: no trip meanwhile
            # (a rig that fell behind the host's time catches up flat out: the host's frames then
            # come far apart in simulated time, and a trip there says so: its lag, in µs)
            assert abs(motor(rig)[2] - 0.75) < 0.01, f"tripped; the rig's {rig.ctl('lag')}"
            t0 = time.monotonic()
            p.send_signal(kill)
            p.wait(10)
            assert wait_for(lambda: motor(rig)[2] == 0.0, 5)
            if kill == signal.SIGTERM:  # goodbye: at once, not after failsafe_ms
                assert time.monotonic() - t0 < 2.0
        finally:
            if p.poll() is None:
                p.kill()
                p.wait(5)


@pytest.mark.parametrize(
    ("entry", "said"),
    [
        ({"driver": "gps_nmea", "uart": 1}, "only UART is the J2A link"),
        ({"driver": "hbridge", "pwm_pin": 9, "dir_pin": 7}, "pwm_pin is 6 or 5"),
        ({"driver": "hbridge", "pwm_pin": 6, "dir_pin": 7, "stop": "brake"}, "needs in1 and in2"),
        ({"driver": "hcsr04", "trig_pin": 7, "echo_pin": 99}, "echo_pin 99 has no pin-change"),
        ({"driver": "stepper", "step_pin": 40, "dir_pin": 7}, "no digital pin 40"),
    ],
)
def test_gen_firmware_refuses_what_the_uno_cannot_do(
    tmp_path: Path, entry: dict[str, object], said: str
) -> None:
    board = {"name": "u", "mcu": "atmega328p", "transducers": [{"name": "x", "id": 0, **entry}]}
    f = tmp_path / "u.py"
    f.write_text(f"BOARD = {board!r}\n")
    with pytest.raises(ConfigError, match=said) as e:
        generate_avr(load_board_file(f))
    assert str(f) in str(e.value) and ": x:" in str(e.value)  # names the file and the entry


@pytest.mark.slow
@pytest.mark.micropython
def test_the_same_keys_and_functions_as_the_micropython_firmware(rig: AvrSim) -> None:
    """The failsafe's and the new drivers' keys: byte for byte what the MicroPython firmware
    serves for the same board file, the functions at the same indices."""
    board = Board(open_transport(rig.url), timeout=5.0)
    try:
        board.handshake()
        avr_keys, avr_index = board.read_many("a2jConfigKeys"), dict(board.index)
    finally:
        board.close()
    mpy = FirmwareSim(ROOT / "examples" / "boards" / "rover-mega.py")
    try:
        b = Board(open_transport(mpy.url), timeout=5.0)
        try:
            b.handshake()
            assert b.read_many("a2jConfigKeys").decode() == avr_keys.decode()
            assert dict(b.index) == avr_index
        finally:
            b.close()
    finally:
        mpy.close()
    assert b"motor_l.failsafe_ms;int;300;0..60000;" in avr_keys
    assert b"servo.safe;enum;limp;hold|limp;" in avr_keys
