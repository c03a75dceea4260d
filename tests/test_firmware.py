"""The MicroPython firmware (board file + runtime + drivers) under the real MicroPython
interpreter with simulated peripherals: the host reads its descriptors and the daemon publishes
what the simulated devices measure; a servo command shows as the PWM pulse width."""

from __future__ import annotations

import math
import socket
import struct
import time
from collections.abc import Iterator
from pathlib import Path

import pytest

from missing_link.daemon import Daemon
from missing_link.host.board import Board
from missing_link.host.config import ConfigRefused
from missing_link.topics import Update
from missing_link.transport import open_transport

from .helpers import FirmwareSim, daemon_up, wait_for

ROOT = Path(__file__).resolve().parent.parent
RIG = ROOT / "examples" / "boards" / "thesis-rig.py"
pytestmark = [pytest.mark.micropython, pytest.mark.slow]
Rig = tuple[Daemon, dict[str, list[Update]]]


@pytest.fixture(scope="module")
def sim() -> Iterator[FirmwareSim]:
    with FirmwareSim(RIG) as s:
        yield s


@pytest.fixture
def daemon(sim: FirmwareSim) -> Iterator[Rig]:
    got: dict[str, list[Update]] = {}
    with daemon_up(sim.url) as d:
        for name in ("wheel", "dist_ir", "sonar", "servo", "bumper", "imu"):
            got[name] = []
            d.subscribe(f"/rig/{name}", got[name].append, queue=0)
        yield d, got


def test_descriptors_come_from_the_board_file(sim: FirmwareSim) -> None:
    board = Board(open_transport(sim.url), timeout=5.0)
    try:
        board.handshake()
        t = {x.name: x for x in board.transducers}
        assert sim.ident.startswith("micropython 1.27")
        assert board.properties["board.name"] == "rig"
        # the wasm port's ticks_us counts in ms: the firmware measures and declares it
        assert board.properties["clock.res_us"] == "1000"
        assert (t["dist_ir"].model, t["dist_ir"].dtype, t["dist_ir"].options["unit"]) == (
            "GP2Y0A02YK",
            "uint16_t",
            "mm",
        )
        assert t["servo"].options["kind"] == "actuator"
        assert t["servo"].options["call"] == "a2j_set_servo"
        assert (t["imu"].chan_count, t["imu"].dtype) == (7, "float")
        assert t["wheel"].id == 0 and t["sonar"].id == 2 and t["bumper"].dtype == "uint8_t"
    finally:
        board.close()


def test_sharp_ranger_follows_the_datasheet_curve(daemon: Rig, sim: FirmwareSim) -> None:
    _, got = daemon
    for mm in (300, 800, 1400):
        sim.ctl(f"WORLD.sharp[26] = {mm}")
        n = len(got["dist_ir"])
        assert wait_for(lambda n=n: len(got["dist_ir"]) > n + 3)
        v = got["dist_ir"][-1].values[0]
        assert abs(v - mm) <= 0.06 * mm, (mm, v)
    # Above the curve's peak (15 cm: 2.75 V) and beyond 150 cm: N/A.  (Between 5 and 15 cm the
    # real sensor gives a voltage that also belongs to a far distance; no driver can tell.)
    for mm in (150, 2500):
        sim.ctl(f"WORLD.sharp[26] = {mm}")
        n = len(got["dist_ir"])
        assert wait_for(lambda n=n: len(got["dist_ir"]) > n + 3)
        assert got["dist_ir"][-1].values[0] is None, mm  # N/A


def test_srf02_ranges_over_i2c_and_changes_address(daemon: Rig, sim: FirmwareSim) -> None:
    _, got = daemon
    sim.ctl("WORLD.i2c[(0, 0x70)].distance_cm = 123")
    n = len(got["sonar"])
    assert wait_for(lambda: len(got["sonar"]) > n + 2)
    assert got["sonar"][-1].values[0] == 123
    # The sample is stamped at the echo: the ping plus half the flight (123 cm: 3.6 ms)
    sim.ctl("WORLD.i2c[(0, 0x70)].echo = False")  # nothing in range: range 0 is N/A
    n = len(got["sonar"])
    assert wait_for(lambda: len(got["sonar"]) > n + 2)
    assert got["sonar"][-1].values[0] is None
    sim.ctl("WORLD.i2c[(0, 0x70)].echo = True")
    # the datasheet's address change sequence, written by the driver, moves the device; asked
    # while a ranging is in flight (the SRF02 acknowledges nothing then), it waits for its end
    # (before: EIO, when the loop happened to be ranging)
    sim.ctl("d = fw.drivers['sonar']\nd.measure(rt.clock())\nd.change_address(0x71)")
    assert sim.ctl("result = sorted(a for (b, a) in WORLD.i2c)") == [0x68, 0x71]
    sim.ctl("WORLD.i2c[(0, 0x71)].distance_cm = 77")
    n = len(got["sonar"])
    assert wait_for(lambda: len(got["sonar"]) > n + 2)
    assert got["sonar"][-1].values[0] == 77
    assert sim.ctl("result = fw.drivers['sonar'].timeouts") == 0


def test_encoder_counts_edges_and_flags_a_missed_one(daemon: Rig, sim: FirmwareSim) -> None:
    _, got = daemon
    base = sim.ctl("result = fw.drivers['wheel'].count")
    sim.ctl("WORLD.encoder_steps(2, 3, 400)")
    assert wait_for(lambda: got["wheel"] and got["wheel"][-1].values[0] == base + 400)
    sim.ctl("WORLD.encoder_steps(2, 3, -150)")
    assert wait_for(lambda: got["wheel"][-1].values[0] == base + 250)
    n = len(got["wheel"])
    sim.ctl("WORLD.encoder_glitch(2, 3)")  # both phases moved between two interrupts
    assert wait_for(lambda: any(u.values[0] is None for u in got["wheel"][n:]))  # N/A
    assert sim.ctl("result = fw.drivers['wheel'].errors") == 1


def test_bumper_is_debounced_and_stamped_at_the_first_edge(daemon: Rig, sim: FirmwareSim) -> None:
    _, got = daemon
    n = len(got["bumper"])
    # pressed: a switch to ground, bouncing 6 times
    t0 = sim.ctl("result = rt.clock(); WORLD.bounce(14, 0, 6)")
    assert wait_for(lambda: len(got["bumper"]) > n)
    time.sleep(0.2)
    pressed = got["bumper"][n:]
    assert [u.values[0] for u in pressed] == [1]  # one report for 13 edges
    # stamped at the first edge (same 1 ms tick of the wasm clock), not 20 ms later when the
    # debounce ended
    assert t0 <= pressed[0].board_us[0] <= t0 + 1000
    sim.ctl("WORLD.bounce(14, 1, 3)")
    assert wait_for(lambda: len(got["bumper"]) > n + 1)
    assert got["bumper"][-1].values[0] == 0


def test_imu_scaling_and_bus_loss(daemon: Rig, sim: FirmwareSim) -> None:
    _, got = daemon
    sim.ctl("m = WORLD.i2c[(0, 0x68)]; m.accel_g = (0.5, -1.0, 0.25); m.gyro_dps = (90, 0, -45)")
    sim.ctl("m = WORLD.i2c[(0, 0x68)]; m.temp_c = 31.5")
    n = len(got["imu"])
    assert wait_for(lambda: len(got["imu"]) > n + 5)
    v = got["imu"][-1].values
    assert v[0] == pytest.approx(0.5 * 9.80665, abs=0.01)
    assert v[1] == pytest.approx(-9.80665, abs=0.01)
    assert v[3] == pytest.approx(31.5, abs=0.01)
    assert v[4] == pytest.approx(math.pi / 2, abs=0.01)
    assert v[6] == pytest.approx(-math.pi / 4, abs=0.01)
    # the IMU drops off the bus: N/A on every channel, then it is re-initialised
    sim.ctl("dev = WORLD.i2c.pop((0, 0x68))")
    n = len(got["imu"])
    assert wait_for(lambda: any(u.values[0] is None for u in got["imu"][n:]))
    sim.ctl("devices.MPU6050(0, 0x68).accel_g = (0, 0, 1)")
    assert wait_for(lambda: got["imu"][-1].values[2] == pytest.approx(9.80665, abs=0.01))


def test_servo_command_sets_the_pulse_width(daemon: Rig, sim: FirmwareSim) -> None:
    d, got = daemon
    assert sim.ctl("result = WORLD.pulse_us(15)") == 0  # limp until the first command
    assert sim.ctl("result = WORLD.pwms[15].freq()") == 50
    for value, pulse in ((0, 1500), (127, 2100), (-64, 1198), (-127, 900)):
        d.send("/rig/servo/cmd", value)
        assert wait_for(lambda v=value: got["servo"] and got["servo"][-1].values[0] == v)
        assert sim.ctl("result = WORLD.pulse_us(15)") == pulse


def test_values_are_mapped_into_host_time(daemon: Rig) -> None:
    d, got = daemon
    assert wait_for(lambda: d.status()[0].get("sync_state") == "tracking", 15)
    u = got["imu"][-1]
    assert abs(u.host_ns[0] - time.time_ns()) < 2e9  # (host times are wall clock)
    assert u.bound_ns > 0  # the 1 ms tick of the wasm clock is in the bound


def test_the_break_between_frames_gives_the_repl_back() -> None:
    """Ctrl-C twice, "repl", Enter (what `missing-link flash` sends before mpremote takes
    over; tests/test_board_safety.py: what does not stop it)."""
    s = FirmwareSim(RIG)
    try:
        host, port = s.url[len("tcp://") :].split(":")
        with socket.create_connection((host, int(port)), timeout=5) as c:
            c.sendall(b"\r\x03\x03repl\r")
            assert s.next_line(10) == "BREAK"
    finally:
        s.close()


def test_configuration_reaches_the_simulated_devices(sim: FirmwareSim) -> None:
    """Run-time configuration on the real drivers under MicroPython: a new rate shows as the
    SRF02's rangings at the device, a disabled ranger is not read at all, a new IMU range is
    written to the chip's register, servo limits clamp the pulse; saved, it is applied at the
    next boot."""
    board = Board(open_transport(sim.url), timeout=5.0)

    def per_s(expr: str, seconds: float = 2.0) -> float:
        a = sim.ctl(f"result = {expr}")
        time.sleep(seconds)
        return float(sim.ctl(f"result = {expr}") - a) / seconds

    sonar = "WORLD.i2c[(0, fw.drivers['sonar'].address)].rangings"
    try:
        board.handshake()
        assert board.config()["sonar.rate_hz"] == 10.0
        board.configure({"sonar.rate_hz": 2})
        assert 1.0 <= per_s(sonar) <= 3.0
        board.configure({"sonar.rate_hz": 10})
        assert 8.0 <= per_s(sonar) <= 11.0
        board.configure({"dist_ir.enabled": False})
        time.sleep(0.1)
        assert per_s("WORLD.adc_reads", 1.0) == 0  # not polled at all
        board.configure({"dist_ir.enabled": True})
        assert per_s("WORLD.adc_reads", 1.0) > 30  # 25 Hz x 3 reads
        board.configure({"imu.accel_g": 8, "imu.dlpf": 5})
        assert wait_for(lambda: sim.ctl("result = WORLD.i2c[(0, 0x68)].regs[0x1C]") == 2 << 3)
        assert sim.ctl("result = WORLD.i2c[(0, 0x68)].regs[0x1A]") == 5
        assert board.call("a2j_set_servo", struct.pack("<b", 127)).code == 0
        board.configure({"servo.max_us": 1800})
        assert sim.ctl("result = WORLD.pulse_us(15)") == 1800  # the held pulse, re-clamped
        with pytest.raises(ConfigRefused, match="min_us < centre_us < max_us"):
            board.configure({"servo.max_us": 1400})
        board.configure({"sonar.rate_hz": 5, "imu.accel_g": 4}, save=True)
        sim.ctl("reboot()")
        after = board.config()
        assert after["sonar.rate_hz"] == 5.0 and after["imu.accel_g"] == 4
        assert after["servo.max_us"] == 1800 and board.settings.state & 3 == 3
        board.reset_config(erase_saved=True)
        sim.ctl("reboot()")
        assert board.config()["sonar.rate_hz"] == 10.0
    finally:
        board.close()


def test_aligned_sampling_and_a_timed_trigger_on_micropython() -> None:
    """Given a map of the board's clock (a2jHostMap), an aligned ranger's ADC reads at the
    simulated device fall on the host-time grid in board ticks, and a timed trigger's edge at
    the device lands on the tick its host time maps to.  In simulated time (host.mjs --fast:
    the board's clock moves by what its work costs on a Pico, simcost.py, never by how long a
    loaded machine kept node waiting for a core, which made a read in real time up to 25 ms
    late with the garbage collector off altogether: docs/hardware.md, "Memory"); --lead-ms
    keeps it within 200 ms of this host's last bytes, so a map stays fresh."""
    sim = FirmwareSim(RIG, args=["--fast", "--lead-ms", "200"])
    board = Board(open_transport(sim.url), timeout=5.0)

    def wait_board(until: int) -> None:  # (the simulation moves on as this host talks to it)
        assert wait_for(lambda: board.clock_exchange(5.0).t3 >= until, 60, step=0.01)

    try:
        board.handshake()
        now = board.clock_exchange(5.0).t3
        h0 = 1_795_000_000_000_000_000 + 3_456_789  # host ns (any epoch will do)
        board.call_ok("a2jHostMap", struct.pack("<Qqi", now, h0, 0))

        # the device logs time.ticks_us(); the board's clock extends it to 64 bit (its own
        # origin): the same instant in both
        board_now, raw_now = sim.ctl("import time; result = (rt.clock(), time.ticks_us())")

        def host(tick: int) -> int:
            return h0 + (tick - now) * 1000

        def board_tick(raw: int) -> int:
            return raw - raw_now + board_now

        board.configure({"dist_ir.aligned": True, "dist_ir.rate_hz": 10, "dist_ir.phase": 0.25})
        # the log from after the configuration took effect: reads before it were free-running,
        # and the one read planned under the old plan is the first (skipped below)
        sim.ctl("WORLD.adc_log.clear()")
        wait_board(board.clock_exchange(5.0).t3 + 1_500_000)
        reads = sim.ctl("result = list(WORLD.adc_log)")
        firsts = [t for i, t in enumerate(reads) if i == 0 or t - reads[i - 1] > 5_000]
        assert len(firsts) >= 10  # 10 Hz, 3 conversions each
        for t in firsts[1:]:
            off = (host(board_tick(t)) - 25_000_000) % 100_000_000
            assert min(off, 100_000_000 - off) <= 2_000_000, off
        board.configure({"dist_ir.aligned": False})
        sim.ctl("WORLD.edges.clear()")
        soon = board.clock_exchange(5.0).t3 + 500_000  # half a second from now
        at = host(soon)
        tick = struct.unpack(
            "<Q",
            board.call_ok("a2jAt", struct.pack("<qB", at, board.index["a2j_trigger"]) + b"\0\0"),
        )[0]
        assert tick == soon
        wait_board(tick + 300_000)
        edges = sim.ctl("result = WORLD.edges.get(16, [])")
        assert [level for _t, level in edges] == [1, 0]
        assert 0 <= board_tick(edges[0][0]) - tick <= 2_000, (edges, tick)
        assert board.call_ok("a2jAlignInfo")[0] == 1  # the map is valid
    finally:
        board.close()
        sim.close()


def test_aligned_reads_stay_on_time_beside_a_free_running_imu() -> None:
    """The rig's MPU-6050 holds the board's one loop about 1.6 ms of a Pico's time a read
    (simulated time, as above); at 97 Hz its reads drift through every phase of the aligned
    ranger's 10 Hz grid.  A read under way at an instant made that ADC read late by what was
    left of it: 5 of 199 over 2 ms, 25 over 1 ms (max 2.24 ms) in 20 board seconds.  Now an IMU
    read waits for room before an instant (board/pacing.py): none over 1 ms, the reads put off
    counted in a2jAlignInfo, none reaching an instant."""
    sim = FirmwareSim(RIG, args=["--fast", "--lead-ms", "200"])
    board = Board(open_transport(sim.url), timeout=5.0)
    raw: list[int] = []  # the device's ticks_us of each ADC read
    try:
        board.handshake()
        now = board.clock_exchange(5.0).t3
        h0 = 1_795_000_000_000_000_000 + 3_456_789

        def host(tick: int) -> int:
            return h0 + (tick - now) * 1000

        board.call_ok("a2jHostMap", struct.pack("<Qqi", now, h0, 0))
        board_now, raw_now = sim.ctl("import time; result = (rt.clock(), time.ticks_us())")
        board.configure({"imu.rate_hz": 97.0})
        board.configure({"dist_ir.aligned": True, "dist_ir.rate_hz": 10, "dist_ir.phase": 0.25})
        sim.ctl("WORLD.adc_log.clear()")
        taken = start = board.clock_exchange(5.0).t3
        while taken < start + 20_000_000:
            t3 = board.clock_exchange(5.0).t3
            # a map vouches for 10 s around its reference: the same line, a new one now
            board.call_ok("a2jHostMap", struct.pack("<Qqi", t3, host(t3), 0))
            if t3 - taken >= 2_000_000:  # (the device keeps its newest 2000 reads)
                raw += sim.ctl("result = list(WORLD.adc_log); WORLD.adc_log.clear()")
                taken = t3
            time.sleep(0.05)
        info = board.call_ok("a2jAlignInfo")
    finally:
        board.close()
        sim.close()
    reads = [board_now + (t - raw_now) % (1 << 30) for t in raw]  # (ticks_us wraps at 2^30)
    firsts = [t for i, t in enumerate(reads) if i == 0 or t - reads[i - 1] > 5_000]
    offs = []
    for t in firsts[1:]:  # (the first was planned under the old plan)
        off = (host(t) - 25_000_000) % 100_000_000
        offs.append(min(off, 100_000_000 - off))
    assert len(offs) >= 190
    assert max(offs) <= 1_000_000, sorted(offs)[-5:]
    deferred, overlaps = struct.unpack("<II", info[17:])
    assert deferred > 0 and overlaps == 0
