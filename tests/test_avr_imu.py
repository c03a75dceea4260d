"""The MPU-6050 on AVR (issue 46.3), as on MicroPython (board/drivers/mpu6050.py): the same
descriptor, channels, units, keys and standard types (Imu + Temperature), the same bus faults
(said once a kind, counted, the chip set up again); its 14-byte burst on a TWI it shares with an
SRF02, in simavr with the chip modelled from its register map (firmware/avr/sim/mpu6050.c)."""

from __future__ import annotations

import math
import struct
import subprocess
import sys
import threading
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

from missing_link.board.drivers import driver_class
from missing_link.board.firmware import describe
from missing_link.deploy.avr import AVR_DIR
from missing_link.deploy.boardfile import load_board_file
from missing_link.descriptors import Transducer, parse_transds
from missing_link.host.board import Board
from missing_link.ros.standard import mappings_for
from missing_link.transport import open_transport

from .helpers import AvrSim, FirmwareSim, wait_for
from .test_standard import STORE

ROOT = Path(__file__).resolve().parent.parent
IMU = ROOT / "tests" / "boards" / "imu-uno.py"
PARTS = ("mpu6050 0x68", "srf02 0x70")
G = 9.80665
pytestmark = [pytest.mark.avr, pytest.mark.slow]


@pytest.fixture(scope="module")
def build(avr_build: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("imu")
    r = subprocess.run(
        ["make", "-C", str(AVR_DIR), f"BOARD={IMU}", f"BUILD={out}", f"PYTHON={sys.executable}"],
        capture_output=True, text=True, timeout=300,
    )  # fmt: skip
    assert r.returncode == 0, r.stdout + r.stderr
    return out


class Samples:
    """The newest SIF of the IMU (tid 0): its 7 stamps and values."""

    def __init__(self, board: Board) -> None:
        self.lock = threading.Lock()
        self.n = 0
        self.values: tuple[float, ...] = ()
        board.on_sif(0, self._on)

    def _on(self, sif, _rx) -> None:  # type: ignore[no-untyped-def]
        fields = struct.unpack("<" + "Qf" * 7, sif.payload)
        with self.lock:
            self.n += 1
            self.values = fields[1::2]

    def after(self, n: int) -> tuple[float, ...]:
        assert wait_for(lambda: self.n > n, 5), "no SIF"
        with self.lock:
            return self.values


@pytest.fixture
def imu(avr_build: Path, build: Path) -> Iterator[tuple[AvrSim, Board, Samples]]:
    sim = AvrSim(avr_build, build / "imu_uno" / "firmware.elf", parts=PARTS)
    board = Board(open_transport(sim.url), timeout=3.0)
    try:
        board.handshake()
        yield sim, board, Samples(board)
    finally:
        board.close()
        sim.close()


def _shape(t: Transducer) -> tuple[object, ...]:
    """A transducer as its fields say it (N/A: NaN is never equal to itself)."""
    na = "nan" if isinstance(t.na, float) and math.isnan(t.na) else t.na
    return (t.name, t.id, t.prefix, t.model, t.chan_count, t.dtype, na, t.options)


def settle(s: Samples) -> tuple[float, ...]:
    """A sample taken after what the rig was told (the one under way may be older)."""
    n = s.n
    s.after(n)
    return s.after(s.n)


def expect(
    accel: tuple[float, ...], gyro: tuple[float, ...], temp: float, afs: int, fs: int
) -> list[float]:
    """What the driver says for what the chip feels: the chip's integers (rounded, as the
    rig's model and the datasheet have them) scaled as board/drivers/mpu6050.py scales them."""
    lsb_g, lsb_dps = 16384 >> afs, 131.0 / (1 << fs)
    a = [round(x / G * lsb_g) * (G / lsb_g) for x in accel]
    w = [round(math.degrees(x) * lsb_dps) * (math.radians(1) / lsb_dps) for x in gyro]
    return [*a, round((temp - 36.53) * 340) / 340.0 + 36.53, *w]


def test_at_rest_then_moving_in_si_units(imu: tuple[AvrSim, Board, Samples]) -> None:
    sim, _board, s = imu
    got = settle(s)  # at rest, level, 25 degC: 1 g up
    assert got == pytest.approx(expect((0, 0, G), (0, 0, 0), 25.0, 0, 0), rel=1e-6, abs=1e-6)
    feel = (1.5, -2.25, 9.0), (0.1, -0.2, 0.3)
    assert sim.ctl(f"imu {' '.join(map(str, feel[0] + feel[1]))} 31.5") == "ok"
    got = settle(s)
    assert got == pytest.approx(expect(*feel, 31.5, 0, 0), rel=1e-6, abs=1e-6)
    assert sim.ctl("imu_regs").split()[2:] == ["01", "03", "00", "00"]  # awake, DLPF 3, ranges


def test_ranges_and_filter_set_at_run_time(imu: tuple[AvrSim, Board, Samples]) -> None:
    sim, board, s = imu
    board.configure({"imu.accel_g": 16, "imu.gyro_dps": 2000, "imu.dlpf": 6})
    feel = (30.0, -60.0, 9.8), (5.0, -7.5, 30.0)  # beyond the defaults' +-2 g, +-250 deg/s
    assert sim.ctl(f"imu {' '.join(map(str, feel[0] + feel[1]))} 25") == "ok"
    got = settle(s)
    assert sim.ctl("imu_regs").split()[2:] == ["01", "06", "18", "18"]
    assert got == pytest.approx(expect(*feel, 25.0, 3, 3), rel=1e-6, abs=1e-6)
    assert board.config()["imu.accel_g"] == 16


def test_a_bus_fault_is_said_once_a_kind_counted_and_the_chip_set_up_again(
    imu: tuple[AvrSim, Board, Samples],
) -> None:
    sim, board, s = imu
    lines: list[bytes] = []
    board.on_sif(0xFE, lambda sif, _rx: lines.append(sif.payload))
    settle(s)
    assert sim.ctl("imu_absent 1") == "ok"
    assert wait_for(lambda: all(math.isnan(v) for v in s.after(s.n)), 5)  # N/A on all seven
    for _ in range(5):
        assert all(math.isnan(v) for v in s.after(s.n))
    # the read failing: a bus error; then the set-up it tries again: not answering; once each
    assert wait_for(lambda: len(lines) >= 2, 5)
    said = [(p[8], p[9], p[10]) for p in lines]  # level, source (the IMU's id), kind
    assert said == [(30, 0, 3), (30, 0, 1)], said
    assert sim.ctl("imu_absent 0") == "ok"
    got = settle(s)
    assert got == pytest.approx(expect((0, 0, G), (0, 0, 0), 25.0, 0, 0), rel=1e-6, abs=1e-6)
    info = board.call_ok("a2jLogInfo")
    said_n, _dropped, _other, n = struct.unpack_from("<IIIB", info)
    rows = [struct.unpack_from("<BBI", info, 13 + 6 * i) for i in range(n)]
    faults = {(src, kind): count for src, kind, count in rows}
    assert faults[(0, 1)] >= 5 and faults[(0, 3)] == 1 and said_n == 2
    assert len(lines) == 2  # (counted, never said again)


def test_a_burst_is_one_sample_when_the_link_cannot_carry_them_all(
    imu: tuple[AvrSim, Board, Samples],
) -> None:
    """1000 bursts a second, ~120 SIFs of 7 channels the link carries: the older sample that
    has no room when a new burst comes is dropped whole.  Dropping only the channel being
    written tore it: the next channel found room (the UART had drained a byte), went out beside
    older values, and the rest followed with N/A in front (an Imu with NaN acceleration)."""
    _sim, board, _s = imu
    sifs: list[tuple[float, ...]] = []
    lost: list[int] = []  # (the SIFs the seq says were lost before each: the drops, shown)

    def on_sif(sif: Any, _rx: int) -> None:
        sifs.append(struct.unpack("<" + "Qf" * 7, sif.payload))
        lost.append(sif.lost)

    board.on_sif(0, on_sif)
    board.configure({"imu.rate_hz": 1000})
    assert wait_for(lambda: len(sifs) >= 400, 30)
    got = sifs[20:400]  # (after the rate took)
    span_us = got[-1][0] - got[0][0]
    assert len(got) < span_us / 1000 / 2  # most bursts had no room: the drop path ran
    # each burst went out or was dropped, and a drop takes its seq, as the Python runtime's
    # queue's does, so the host counts it (lost_sifs): the bursts between the first and the
    # last sample are those sent and those lost, one a ms or a little less often (the loop's
    # own time).  Before, an AVR's drops took no seq: counted on the board, shown nowhere
    bursts = len(got) - 1 + sum(lost[21:400])
    assert 1000 <= span_us / bursts < 2000, (span_us, bursts)
    torn = [f for f in got if len(set(f[0::2])) != 1 or 0 < sum(map(math.isnan, f[1::2])) < 7]
    assert torn == [], f"{len(torn)} of {len(got)} samples torn: {torn[:3]}"


@pytest.mark.micropython
def test_the_same_descriptor_keys_and_values_as_the_micropython_firmware(
    imu: tuple[AvrSim, Board, Samples],
) -> None:
    sim, board, s = imu
    bf = load_board_file(IMU)
    line = describe(bf.transducers[0], driver_class("mpu6050")).descriptor_line()
    transds = board.read_many("a2jGetTransds").decode()
    assert line in transds.splitlines()
    t = parse_transds(transds)[0]
    assert [m.type_name for m in mappings_for(t, "imu_uno", STORE)] == [
        "sensor_msgs/msg/Imu",
        "sensor_msgs/msg/Temperature",
    ]
    avr_keys = board.read_many("a2jConfigKeys")
    feel_g, feel_dps = (0.25, -0.5, 0.875), (10.0, -20.0, 45.0)
    assert (
        sim.ctl(
            "imu "
            + " ".join(str(x * G) for x in feel_g)
            + " "
            + " ".join(str(math.radians(x)) for x in feel_dps)
            + " 30"
        )
        == "ok"
    )
    avr = settle(s)
    mpy = FirmwareSim(IMU)
    try:
        mpy.ctl(
            "d = [v for k, v in WORLD.i2c.items() if k[1] == 0x68][0]\n"
            f"d.accel_g = {feel_g}\nd.gyro_dps = {feel_dps}\nd.temp_c = 30.0\nresult = 0"
        )
        with Board(open_transport(mpy.url), timeout=5.0) as b:
            b.handshake()
            assert b.read_many("a2jConfigKeys") == avr_keys
            # (the same transducers: MicroPython orders the options of its own dict its way)
            same = [_shape(t) for t in parse_transds(b.read_many("a2jGetTransds").decode())]
            assert same == [_shape(t) for t in parse_transds(transds)]
            m = Samples(b)
            values = m.after(m.n)
            values = m.after(m.n)
    finally:
        mpy.close()
    assert avr == pytest.approx(values, rel=1e-6, abs=1e-6)
