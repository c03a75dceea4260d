"""The AVR world's own CPU (issue 47.6), steadier than bench_world.py's process figures on a
shared machine: the AVR rover (rover-mega.py in simavr) with bench_world's world (1 m from its
wall, its sonar held) in this process, as `board --file --runtime avr` wires it, a daemon
driving it at ``--duty``.  Per round: the world's ticks per simulated second (those the rig
made), the CPU of the thread that runs it (the one that reads the rig: world_avr.py) per
simulated second and per tick, of it the world link's (``time.thread_time`` around
WorldLink.ahead, its going back included), the ticks a batch made (the rest asked again where
the drives changed), and the rig's (simavr's) CPU.  Simulated seconds from the rig's ``stats``.

    .venv/bin/python bench/bench_world_avr.py [--seconds 12] [--rounds 3] [--duty 0.5]
"""

from __future__ import annotations

import argparse
import os
import threading
import time
from typing import Any

from bench_world import ROVER, drive, world_file
from missing_link.daemon import Daemon
from missing_link.daemon.config import BoardSpec, Config
from missing_link.deploy.avrsim import build
from missing_link.deploy.boardfile import load_board_file
from missing_link.virtual.avrboard import AvrBoard
from missing_link.virtual.world_avr import AvrWorld, sim_us
from missing_link.virtual.worldlink import WorldLink
from missing_link.world.world import World
from missing_link.world.worldfile import parse

TICK_S = os.sysconf("SC_CLK_TCK")
AVR_ROVER = ROVER.with_name("rover-mega.py")  # (bench_world's AVR rover)


def cpu_s(path: str) -> float:
    with open(path) as f:
        fields = f.read().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / TICK_S


def one_round(duty: float, seconds: float) -> dict[str, float]:
    bf = load_board_file(AVR_ROVER)
    board: dict[str, Any] = dict(bf.board)
    server = AvrBoard(build(bf, "avr-0123456789ab").command(), "tcp://127.0.0.1:0")
    link = WorldLink(
        World(parse(world_file("avr").read_text(), "w"), board, sim_us(server.ctl)), board
    )
    spent = [0.0]
    ahead = link.ahead

    def timed(now: int, used: int, values: list[int]) -> Any:
        c = time.thread_time()
        got = ahead(now, used, values)
        spent[0] += time.thread_time() - c
        return got

    link.ahead = timed  # type: ignore[method-assign,assignment]
    hand = AvrWorld(link, server.ctl_lines, board["transducers"], (), server.ctl_post)
    server.on_tick = hand.answer
    hand.start()
    threading.Thread(target=server.serve_forever, daemon=True).start()
    reader = next(t.native_id for t in threading.enumerate() if t.name == "board:rig")
    thread = f"/proc/self/task/{reader}/stat"
    try:
        with Daemon(
            Config(boards=[BoardSpec(server.url, timeout=3.0, handshake_timeout=20.0)])
        ) as d:
            if not d.wait_until_up(60):
                raise SystemExit(f"no daemon on the rover: {d.status()}")
            drive(d, duty, "mega_rover")
            time.sleep(3.0)
            s0, c0, r0, n0 = (
                sim_us(server.ctl),
                cpu_s(thread),
                cpu_s(f"/proc/{server.proc.pid}/stat"),
                [spent[0], hand.ticks, link.batches],
            )
            t0 = time.monotonic()
            while time.monotonic() - t0 < seconds:
                time.sleep(0.5)
                drive(d, duty, "mega_rover")
            s1, c1, r1 = sim_us(server.ctl), cpu_s(thread), cpu_s(f"/proc/{server.proc.pid}/stat")
            n1 = [spent[0], hand.ticks, link.batches]
    finally:
        server.stop()
    if hand.failed:
        raise SystemExit(f"the world failed: {hand.failed}")
    sim_s, ticks = (s1 - s0) / 1e6, int(n1[1] - n0[1])
    return {"ticks_s": ticks / sim_s, "cpu": (c1 - c0) / sim_s * 100,
            "us_tick": (c1 - c0) / ticks * 1e6, "link_us": (n1[0] - n0[0]) / ticks * 1e6,
            "per_batch": ticks / max(1, n1[2] - n0[2]),
            "rig": (r1 - r0) / sim_s * 100, "load": os.getloadavg()[0]}  # fmt: skip


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seconds", type=float, default=12.0)
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--duty", type=float, default=0.5)
    a = ap.parse_args()
    print("| round | ticks a simulated s | world's thread, % of a core | µs a tick | of it the "
          "world link's, µs | ticks a batch | the rig's CPU, % | load |")  # fmt: skip
    print("|---|---|---|---|---|---|---|---|")
    for k in range(a.rounds):
        r = one_round(a.duty, a.seconds)
        print(f"| {k + 1} | {r['ticks_s']:.1f} | {r['cpu']:.2f} | {r['us_tick']:.0f} | "
              f"{r['link_us']:.0f} | {r['per_batch']:.1f} | {r['rig']:.1f} | "
              f"{r['load']:.1f} |")  # fmt: skip


if __name__ == "__main__":
    main()
