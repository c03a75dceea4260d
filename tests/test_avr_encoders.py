"""Two and more quadrature encoders on AVR (issue 46.2): each phase's pin on its own external
interrupt (INT0/INT1 on an Uno, INT0-INT5 on a Mega) or on its port's pin-change interrupt
beyond, each encoder x4-decoded with the newest edge's stamp, in simavr with the edges made at
those pins (firmware/avr/sim/encoder.c); and the generator's checks of the pins."""

from __future__ import annotations

import struct
import subprocess
import sys
import threading
from collections.abc import Iterator
from pathlib import Path

import pytest

from missing_link.deploy.avr import AVR_DIR
from missing_link.deploy.avrgen import generate_avr
from missing_link.deploy.boardfile import load_board_file
from missing_link.errors import ConfigError
from missing_link.host.board import Board
from missing_link.transport import open_transport

from .helpers import AvrSim, wait_for

NA = -(2**31)
UNO = """BOARD = {"name": "uno_wheels", "mcu": "atmega328p", "transducers": [
    {"name": "left", "id": 0, "driver": "quadrature", "pin_a": 2, "pin_b": 3, "rate_hz": 50},
    {"name": "right", "id": 1, "driver": "quadrature", "pin_a": 4, "pin_b": 5, "rate_hz": 50,
     "reverse": True},
]}
"""
#: the rig's parts at those pins: INT0/INT1 (PD2/PD3), then PCINT20/21 (PD4/PD5)
UNO_PARTS = ("quadrature D2 D3", "quadrature D4 D5")
MEGA = """BOARD = {"name": "mega_wheels", "mcu": "atmega2560", "transducers": [
    {"name": "left", "id": 0, "driver": "quadrature", "pin_a": 2, "pin_b": 3},
    {"name": "right", "id": 1, "driver": "quadrature", "pin_a": 62, "pin_b": 63},
    {"name": "mast", "id": 2, "driver": "quadrature", "pin_a": 64, "pin_b": 65},
]}
"""
#: INT4/INT5 (D2/D3: PE4/PE5), and two encoders on port K's one pin-change interrupt (A8-A11)
MEGA_PARTS = ("quadrature E4 E5", "quadrature K0 K1", "quadrature K2 K3")


@pytest.fixture(scope="module")
def build(avr_build: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    """Both boards' firmware (rig_sim is avr_build's)."""
    out = tmp_path_factory.mktemp("wheels")
    for text, name in ((UNO, "uno"), (MEGA, "mega")):
        board = out / f"{name}.py"
        board.write_text(text)
        r = subprocess.run(
            ["make", "-C", str(AVR_DIR), f"BOARD={board}", f"BUILD={out}",
             f"PYTHON={sys.executable}"],
            capture_output=True, text=True, timeout=300,
        )  # fmt: skip
        assert r.returncode == 0, r.stdout + r.stderr
    return out


class Counts:
    """The newest (board µs, count) of each transducer, from its SIFs, and the first stamp of
    each count."""

    def __init__(self, board: Board, tids: range) -> None:
        self.last: dict[int, tuple[int, int]] = {}
        self.first: dict[tuple[int, int], int] = {}
        self.lock = threading.Lock()
        for tid in tids:
            board.on_sif(tid, self._on)

    def _on(self, sif, _rx) -> None:  # type: ignore[no-untyped-def]
        stamp, value = struct.unpack("<Qi", sif.payload)
        with self.lock:
            self.last[sif.cmd] = (stamp, value)
            self.first.setdefault((sif.cmd, value), stamp)

    def value(self, tid: int) -> int | None:
        with self.lock:
            got = self.last.get(tid)
        return None if got is None else got[1]

    def seen(self, tid: int, value: int) -> bool:
        """Whether a SIF said it (one the next replaces 20 ms on, which a look may miss)."""
        with self.lock:
            return (tid, value) in self.first

    def stamp(self, tid: int) -> int:
        """The stamp the count now came with first: its edge's (later ones: their report's)."""
        with self.lock:
            return self.first[(tid, self.last[tid][1])]


#: the Uno encoders' interrupt routines (vectors): INT0 and INT1 (1, 2), PCINT2 (5, after them)
UNO_VECTORS = ({"1", "2"}, {"5"})
#: cycles from an edge to its routine's read of Timer1 when nothing holds it off: the
#: instruction in flight (5 at most), the interrupt's entry (4) and its vector's jump (3), the
#: routine's saves (32), the call to quadrature_edge (2 + 4) and its saves (12 + 1), the call to
#: clock_now_from_isr (3) and its read of TCNT1 (2)
ENTRY = 68
#: what the rig's irqoff leaves out of a stretch that holds an edge off: a routine's entry (4)
#: and the one instruction the AVR runs after a reti before it takes the next interrupt (5)
AROUND = 9


def stamp_bound_us(off: dict[str, int], k: int) -> float:
    """The latest encoder k's stamp may come after its edge, from the firmware's stretches with
    interrupts off (the rig's irqoff, by vector; cycles at 16 MHz): the stretch in flight when
    the edge comes, then the other encoder's routine if it is of a higher priority (a lower
    vector) and its edge came meanwhile (its next is 100 µs on: once), then this one's entry."""
    own, other = UNO_VECTORS[k], UNO_VECTORS[1 - k]
    first = min(map(int, other)) < min(map(int, own))
    ahead = max(off.get(v, 0) for v in other) + AROUND if first else 0
    worst = max(n + AROUND + (0 if place in other else ahead)
                for place, n in off.items() if place not in own)  # fmt: skip
    return (ENTRY + worst) / 16


def edge_us(sim: AvrSim, k: int) -> tuple[int, float]:
    """Encoder k's edges made so far, and the newest one's board µs."""
    _, _, pos, at = sim.ctl(f"encpos {k}").split()
    return int(pos), float(at)


@pytest.fixture
def uno(avr_build: Path, build: Path) -> Iterator[tuple[AvrSim, Board, Counts]]:
    sim = AvrSim(avr_build, build / "uno_wheels" / "firmware.elf", parts=UNO_PARTS)
    board = Board(open_transport(sim.url), timeout=3.0)
    try:
        board.handshake()
        yield sim, board, Counts(board, range(2))
    finally:
        board.close()
        sim.close()


@pytest.mark.avr
@pytest.mark.slow
def test_two_encoders_on_an_uno_count_apart_stamped_at_their_newest_edge(
    uno: tuple[AvrSim, Board, Counts],
) -> None:
    sim, _board, counts = uno
    assert wait_for(lambda: counts.value(0) == 0 and counts.value(1) == 0, 10)
    sim.ctl("irqoff")  # (from here on)
    assert sim.ctl("enc 0 400") == "ok" and sim.ctl("enc 1 -150") == "ok"  # at once
    assert wait_for(lambda: counts.value(0) == 400 and counts.value(1) == 150, 10), counts.last
    off = dict(place.split(":") for place in sim.ctl("irqoff").split()[1:])
    cycles = {place: int(n) for place, n in off.items()}
    # (the right one is reversed: -150 edges count +150)
    for k in (0, 1):
        pos, at = edge_us(sim, k)
        assert pos == (400, -150)[k]
        assert all(cycles.get(v, 0) < 256 for v in UNO_VECTORS[k]), cycles  # (16 µs: 238 today)
        # the newest edge's stamp: Timer1's count in its interrupt, after the edge by the
        # routines that held its interrupt off (the two encoders' edges come at any phase to
        # each other and to the board's own interrupts: the host says when each starts)
        late = counts.stamp(k) - at
        assert 0 <= late <= stamp_bound_us(cycles, k), (k, counts.stamp(k), at, cycles)
    assert sim.ctl("glitch 1") == "ok"  # both of its phases at once: an edge missed
    assert wait_for(lambda: counts.seen(1, NA), 5)
    assert counts.value(0) == 400  # (the other one goes on as it was)
    assert sim.ctl("enc 1 4") == "ok"
    assert wait_for(lambda: counts.value(1) not in (None, NA), 5)


@pytest.mark.avr
@pytest.mark.slow
def test_three_encoders_on_a_mega_two_sharing_a_pin_change_interrupt(
    avr_build: Path, build: Path
) -> None:
    sim = AvrSim(avr_build, build / "mega_wheels" / "firmware.elf", mcu="atmega2560",
                 parts=MEGA_PARTS)  # fmt: skip
    board = Board(open_transport(sim.url), timeout=3.0)
    try:
        board.handshake()
        counts = Counts(board, range(3))
        assert wait_for(lambda: all(counts.value(k) == 0 for k in range(3)), 10)
        for k, steps in enumerate((-123, 321, 77)):  # edges at the same instants on port K
            assert sim.ctl(f"enc {k} {steps}") == "ok"
        want = {0: -123, 1: 321, 2: 77}
        assert wait_for(lambda: all(counts.value(k) == n for k, n in want.items()), 10), counts.last
        for k in range(3):  # (three interrupts at once: the last stamped up to ~40 µs on)
            pos, at = edge_us(sim, k)
            assert pos == want[k] and 0 <= counts.stamp(k) - at < 60, (k, counts.last, at)
    finally:
        board.close()
        sim.close()


def _board(tmp_path: Path, mcu: str, entries: str) -> Path:
    p = tmp_path / "b.py"
    p.write_text(f'BOARD = {{"name": "b", "mcu": "{mcu}", "buses": {{"twi": {{"id": 0}}}}, '
                 f'"transducers": [{entries}]}}\n')  # fmt: skip
    return p


ENC = '{{"name": "{n}", "id": {i}, "driver": "quadrature", "pin_a": {a}, "pin_b": {b}}}'


def test_the_generator_puts_each_phase_on_its_interrupt(tmp_path: Path) -> None:
    pairs = ((21, 20), (19, 18), (2, 3), (62, 69), (10, 11))
    entries = ",".join(ENC.format(n=f"e{k}", i=k, a=a, b=b) for k, (a, b) in enumerate(pairs))
    src = generate_avr(load_board_file(_board(tmp_path, "atmega2560", entries)))
    for n in range(6):  # INT0..INT5: any change (ISCn0)
        reg, bit = ("EICRA", 2 * n) if n < 4 else ("EICRB", 2 * (n - 4))
        assert f"{reg} |= 1 << {bit}; EIMSK |= 1 << {n};" in src
    assert "PCMSK2 |= 1 << 0;" in src and "PCMSK2 |= 1 << 7;" in src  # A8, A15: port K
    assert "PCMSK0 |= 1 << 4;" in src and "PCMSK0 |= 1 << 5;" in src  # D10, D11: port B
    assert "ISR(PCINT2_vect) { quadrature_edge(&quad_3); }" in src
    assert "ISR(INT1_vect, ISR_ALIASOF(INT0_vect));" in src  # (one routine in flash)


@pytest.mark.parametrize(
    ("mcu", "entries", "said"),
    [
        ("atmega2560", ENC.format(n="w", i=0, a=22, b=23),
         "w: pin_a: pin 22 has no interrupt on the Mega 2560 (external: 2, 3, 18, 19, 20, 21; "
         "pin-change: 10-13, 50-53, 62-69)"),
        ("atmega328p", ENC.format(n="w", i=0, a=0, b=3), "w: pin_a: pin 0 has no interrupt"),
        ("atmega32u4", ENC.format(n="w", i=0, a=3, b=7), "w: pin_b: pin 7 has no interrupt"),
        ("atmega328p", ENC.format(n="w", i=0, a=2, b=3) + "," + ENC.format(n="v", i=1, a=3, b=4),
         "v: pin_a 3 is w (pin_b)'s already"),
        ("atmega2560", ENC.format(n="w", i=0, a=21, b=20)
         + ', {"name": "s", "id": 1, "driver": "srf02", "bus": "twi"}',
         "s: SDA (the TWI) 20 is w (pin_b)'s already"),
        ("atmega2560", ENC.format(n="w", i=0, a=2, b=3)
         + ', {"name": "g", "id": 1, "driver": "gps_nmea", "uart": 1, "pps_pin": 2}',
         "g: pps_pin (INT4) 2 is w (pin_a)'s already"),
        ("atmega328p", ENC.format(n="w", i=0, a=14, b=15)
         + ', {"name": "ir", "id": 1, "driver": "sharp_gp2y0a02", "pin": 1}',
         "ir: pin (A1) 15 is w (pin_b)'s already"),
        ("atmega328p", ",".join(ENC.format(n=f"e{k}", i=k, a=2 + 2 * k, b=3 + 2 * k)
                                for k in range(9)),
         "e8: more than 8 quadrature"),
    ],
)  # fmt: skip
def test_pins_without_an_interrupt_or_taken_are_refused(
    tmp_path: Path, mcu: str, entries: str, said: str
) -> None:
    with pytest.raises(ConfigError, match="b.py: " + said.replace("(", r"\(").replace(")", r"\)")):
        generate_avr(load_board_file(_board(tmp_path, mcu, entries)))
