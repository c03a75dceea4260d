"""rig_sim's side of a world's batches of ticks (firmware/avr/sim/world.c, as world_avr.py speaks
it): each tick's feeds go into the parts at its simulated time (at once when it has passed)
while the asks' answers (the drives) read as the rig last answered them; the rig answers at the
first tick where they do not, or at the batch's end, saying how many it made; a line it
cannot read whole (a time that is not plain digits, beyond 64 bits; a line over RIG_LINE_MAX)
is refused with an error the world sees, never cut or misread (the adversary's findings F4)."""

from __future__ import annotations

import threading
import time
from pathlib import Path
from typing import Any

import pytest

from missing_link.daemon import Daemon
from missing_link.daemon.config import BoardSpec, Config
from missing_link.deploy.avrsim import build
from missing_link.deploy.boardfile import load_board_file
from missing_link.virtual.avrboard import AvrBoard
from missing_link.virtual.world_avr import AvrWorld, sim_us
from missing_link.virtual.worldlink import WorldLink
from missing_link.world.world import World
from missing_link.world.worldfile import parse

from .helpers import AvrRig, AvrSim

pytestmark = [pytest.mark.avr, pytest.mark.slow]
RIG_LINE_MAX = 16383  # (world.h; world_avr.py's)
#: how far ahead of the rig's time a test's ticks are (beyond the line's way there on a busy
#: machine: each tick is then made at its own time, not at the line's coming)
LEAD_US = 300_000
ROVER = Path(__file__).resolve().parents[1] / "examples" / "boards" / "rover-mega.py"
WORLD = """
[start]
x_m = 3.0
[[events]]
at_s = 1.0
kind = "block"
part = "sonar"
distance_m = 0.3
for_s = 0.5
[[events]]
at_s = 2.0
kind = "bump"
"""


@pytest.fixture
def rig(avr_rig: AvrRig) -> AvrSim:
    return avr_rig("mega_rover", rover=True)


def asked(rig: AvrSim, line: str) -> tuple[int, int, str, str]:
    """``line`` sent, its answer (other lines' answers come first: not held behind it) as
    (SIM_US, MADE, the asks' answers, ERRORS FIRST)."""
    assert rig.proc.stdin is not None
    rig.proc.stdin.write(line + "\nlag\n")
    rig.proc.stdin.flush()
    lag = rig.lines.get(timeout=10)
    assert lag is not None and lag.startswith("lag "), lag
    answer = rig.lines.get(timeout=10)
    assert answer is not None and answer.startswith("tick "), answer
    head, errors = answer.split("|")
    _tick, at, made, asks = head.split(" ", 3)
    return int(at), int(made), asks, errors


def encpos(rig: AvrSim) -> int:
    return int(rig.ctl("encpos 0").split()[2])


def test_a_batch_is_made_tick_by_tick_and_answered_at_its_end(rig: AvrSim) -> None:
    assert rig.ctl("wheel 0 off") == "ok"  # (the world's from now: only the feeds turn it)
    _now, made, asks, errors = asked(rig, f"tick motor|{rig.board_us()}")
    assert made == 0 and asks.startswith("motor ") and errors == "0", (made, asks, errors)
    pos0 = encpos(rig)
    t0 = rig.board_us()
    ts = [t0] + [t0 + LEAD_US + 20_000 * k for k in range(4)]
    line = f"tick motor|{ts[0]} enc 0 1|{ts[1]} enc 0 2;nope|{ts[2]}|{ts[3]} enc 0 4|{ts[4]}"
    at, made, again, errors = asked(rig, line)
    assert ts[4] <= at < ts[4] + 2000  # (simulated µs: the rig looks every 1024 instructions)
    assert made == 4 and again == asks
    assert errors == "1 error unknown command: nope"
    assert encpos(rig) == pos0 + 7  # (each tick's edges, 100 µs apart, are in)


def test_the_drives_changing_stop_the_batch_at_that_tick(rig: AvrSim) -> None:
    """The asks here read an encoder's count, which the batch's second tick moves: at its third
    the answers differ from the assumption, and the rig answers there."""
    assert rig.ctl("wheel 0 off") == "ok"
    asked(rig, f"tick encpos 0|{rig.board_us()}")
    t0 = rig.board_us()
    ts = [t0] + [t0 + LEAD_US + 20_000 * k for k in range(4)]
    at, made, asks, errors = asked(
        rig, f"tick encpos 0|{ts[0]}|{ts[1]} enc 0 3|{ts[2]}|{ts[3]}|{ts[4]}"
    )
    assert ts[2] <= at < ts[2] + 2000 and made == 2 and errors == "0"
    assert asks.split()[2] == str(encpos(rig))  # (the count now: the next batch's assumption)


def test_ticks_whose_time_has_passed_are_made_at_once_while_the_drives_hold(rig: AvrSim) -> None:
    asked(rig, f"tick motor|{rig.board_us()}")
    while (now := rig.board_us()) < 100_000:  # (times in the past: the rig's after 0.1 s)
        time.sleep(0.05)
    ts = [now - 30_000, now - 20_000, now - 10_000, now + LEAD_US]
    at, made, _asks, _errors = asked(rig, "tick motor|" + "|".join(map(str, ts)))
    assert made == 3 and ts[3] <= at < ts[3] + 2000  # (the three past at once, each its own)


@pytest.mark.parametrize(
    "line",
    [
        "tick motor|1e6",  # (read as 1 before)
        "tick motor|-5",  # (never answered before)
        "tick motor|18446744073709551616",  # (2^64)
        "tick motor|99999999999999999999999",
        "tick motor|+5",
        "tick motor|5 enc 0 1|3",  # (not after the one before)
        "tick motor|5 enc 0 1|10 enc 0 1",  # (the last entry is a time alone)
        "tick 1000 motor|",  # (the old one-tick line)
        "tick motor",
        "tick",
    ],
)
def test_a_tick_line_it_cannot_read_whole_is_an_error_the_world_sees(
    rig: AvrSim, line: str
) -> None:
    answer = rig.ctl(line)
    assert answer.startswith("error tick: ") and line[:60] in answer, answer
    assert rig.ctl("lag").startswith("lag ")  # (nothing pending, nothing else answered)
    assert rig.lines.empty()


def test_a_line_over_the_rigs_longest_is_refused_whole_said(rig: AvrSim) -> None:
    t = rig.board_us()
    fits = f"tick motor|{t} " + ";".join(["enc 0 0"] * 2000)
    fits = fits[: fits.rindex(";", 0, RIG_LINE_MAX - 20)] + f"|{t + 10_000}"
    assert len(fits) <= RIG_LINE_MAX
    _at, made, _asks, errors = asked(rig, fits)
    assert made == 1 and errors == "0"
    long = f"tick motor|{t} " + ";".join(["enc 0 1"] * 2400) + f"|{t + 10_000}"
    answer = rig.ctl(long)
    assert answer.startswith(f"error tick: line of {len(long)} bytes, over the rig's 16383"), answer
    other = "x" * (RIG_LINE_MAX + 1)
    answer = rig.ctl(other)
    assert answer.startswith(f"error line of {RIG_LINE_MAX + 1} bytes"), answer[:100]
    assert rig.ctl("encpos 0").startswith("encpos 0 ")  # (the next line whole: nothing cut)
    assert rig.lines.empty()


def test_beside_the_driven_firmware_its_parts_get_what_one_tick_at_a_time_gives() -> None:
    """The rover's firmware in simavr driven by a daemon (its motors now forward, now back, now
    still: the rig answers where they change), its world beside it in batches: each tick the rig
    made put into the parts the lines of the world ticked one at a time at the same simulated
    times with the same drives."""
    bf = load_board_file(ROVER)
    board: dict[str, Any] = dict(bf.board)
    server = AvrBoard(build(bf, "avr-0123456789ab").command(), "tcp://127.0.0.1:0")
    t0 = sim_us(server.ctl)

    def world() -> WorldLink:
        return WorldLink(World(parse(WORLD, "room.toml"), board, t0, seed=4), board)

    hand = AvrWorld(world(), server.ctl_lines, board["transducers"], (), server.ctl_post)
    hand.record = []
    server.on_tick = hand.answer
    hand.start()
    threading.Thread(target=server.serve_forever, daemon=True).start()
    reader = next(t for t in threading.enumerate() if t.name == "board:rig")
    try:
        with Daemon(
            Config(boards=[BoardSpec(server.url, timeout=3.0, handshake_timeout=20.0)])
        ) as d:
            assert d.wait_until_up(60), d.status()
            for duty in (0.5, -0.3, 0.0, 0.8, 0.0):
                for side in ("l", "r"):
                    d.send(f"/mega_rover/motor_{side}/cmd", duty)
                time.sleep(0.6)
    finally:
        server.stop()
    reader.join(10)  # (the thread that hands the world the rig's answers: none comes after)
    assert not reader.is_alive()
    assert hand.failed is None and hand.rig_errors == 0, hand.state()
    made = list(hand.record)
    one = AvrWorld(world(), server.ctl_lines, board["transducers"])
    for t, values, lines in made:
        assert one.tick(t, values) == lines, t
    ticks = len(made)
    assert ticks == hand.ticks > 200 and sum("enc 0" in " ".join(x[2]) for x in made) > 20
    batches = hand.link.batches
    assert ticks / 10 < batches < ticks and hand.link.rewound > 0  # (whole ones, and cut short)
