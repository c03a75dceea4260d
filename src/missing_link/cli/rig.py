"""The thesis test rig on virtual boards (``missing-link demo`` runs it).

Board A (encoder + servo) and board B (IR and ultrasonic rangers) each run in their own process
behind a real pseudo-terminal.  The daemon connects both, publishes every transducer and records
everything to a rosbag2/MCAP directory.  The thesis test application closes the loop: each
encoder update becomes a proportional servo deflection, sent back to board A through the
actuator topic ``/board_a/servo/cmd`` (an RPC of ``a2j_set_servo``).  A live terminal view shows
per topic rate, latency and last value, per board link state and errors; at the end (``duration``
or Ctrl-C) a summary.  Exit code 0 when both boards stayed up, samples flowed and the servo moved.

The latency shown is from the board's moment of measurement (the sample's synchronised host
time) to its arrival at the host (view.py).
"""

from __future__ import annotations

import subprocess
import sys
import threading
from dataclasses import dataclass
from typing import Any, TextIO

from ..daemon import Daemon
from ..daemon.config import BoardSpec, Config
from ..errors import MissingLinkError
from ..topics import Update
from ..virtual.process import start_board_process, stop_process
from .view import LiveView

ENCODER_TOPIC = "/board_a/quad"
SERVO_CMD = "/board_a/servo/cmd"
COUNTS_PER_STEP = 64  # encoder counts per servo step (2000 counts = one wheel turn)


def _foxglove(port: int | None) -> Any:
    """The Foxglove live view on ``port`` (another free port if that one is taken)."""
    if port is None:
        return None
    from ..publishers.base import PublisherError
    from ..publishers.foxglove import FoxglovePublisher

    try:
        return FoxglovePublisher({"port": port})
    except PublisherError:  # port taken: any free one will do for a demo (a bug: raised)
        return FoxglovePublisher({"port": 0})


def _web(addr: str | None) -> Any:
    """The device console at ``addr`` (another free port if that one is taken; None: none)."""
    if addr is None or addr == "off":
        return None
    from ..publishers.base import PublisherError
    from ..publishers.web import WebPublisher, parse_addr

    host, port = parse_addr(addr)
    try:
        return WebPublisher({"host": host, "port": port})
    except PublisherError:  # port taken: any free one will do for a demo
        return WebPublisher({"host": host, "port": 0})


@dataclass
class _Seen:
    """What one demo run saw, read before the daemon closed."""

    view: LiveView
    status: list[dict[str, Any]]
    publishers: list[dict[str, Any]]
    failures: list[str]
    mcap: Any
    interrupted: bool


def run_demo(
    duration: float = 20.0,
    seed: int = 0,
    record: str = "recordings",
    out: TextIO = sys.stdout,
    foxglove_port: int | None = 8765,
    web: str | None = None,
) -> int:
    print(
        "missing-link demo: the thesis test rig on two virtual boards (own processes, ptys)",
        file=out,
    )
    procs: list[subprocess.Popen[str]] = []
    try:
        proc_a, url_a = start_board_process("encoder_servo", seed, "pty", name="board_a")
        procs.append(proc_a)
        proc_b, url_b = start_board_process("rangers", seed, "pty", name="board_b")
        procs.append(proc_b)
        print(
            f"  board A (encoder + servo) at {url_a}\n  board B (IR + sonar) at {url_b}", file=out
        )
        cfg = Config(
            boards=[BoardSpec(url_a), BoardSpec(url_b)],
            publishers=["bus", "mcap"],
            publisher_options={"mcap": {"path": record, "prefix": "demo"}},
        )
        seen = _run(cfg, duration, foxglove_port, web, out)
        ok = _summary(seen, out)
    except MissingLinkError as e:
        print(f"demo FAILED: {e}", file=out)
        return 1
    finally:
        for p in procs:
            stop_process(p)
    if seen.interrupted:
        print("demo interrupted", file=out)
        return 130
    print("demo " + ("finished OK" if ok else "FAILED"), file=out)
    return 0 if ok else 1


def _run(
    cfg: Config, duration: float, foxglove_port: int | None, web: str | None, out: TextIO
) -> _Seen:
    """The daemon with its live faces, the thesis test application closing the loop, the live
    view until ``duration`` or Ctrl-C."""
    fox = _foxglove(foxglove_port)
    console = _web(web)
    extra = [p for p in (fox, console) if p is not None]
    interrupted = False
    with Daemon(cfg, extra) as daemon:
        if fox is not None:
            print(f"  live view for Foxglove: open connection {fox.url}", file=out)
        if console is not None:
            print(f"  device console in a browser: {console.url}", file=out)
        if not daemon.wait_until_up(10.0):
            raise MissingLinkError(f"boards did not come up: {daemon.status()}")
        view = LiveView(daemon, out, title="missing-link demo")

        def steer(u: Update) -> None:
            # The thesis test application: encoder count -> proportional servo deflection.
            count = u.values[0]
            if count is not None:
                step = max(-127, min(127, int(count) // COUNTS_PER_STEP))
                daemon.send(SERVO_CMD, step)

        steering = daemon.subscribe(ENCODER_TOPIC, steer)
        try:
            view.run(threading.Event(), duration)
        except KeyboardInterrupt:
            interrupted = True
        steering.cancel()  # no commands into boards that are closing
        view.close()
        return _Seen(
            view=view,
            status=daemon.status(),
            publishers=daemon.publisher_status(),
            failures=daemon.failures(),
            mcap=next(p for p in daemon.publishers if p.name == "mcap"),
            interrupted=interrupted,
        )


#: what the topic lines of the summary count (a newcomer asked)
LEGEND = (
    "  (samples: channel values that arrived, a topic of 8 channels counting 8 per update; N/A:",
    "  channels the board sent without a value, e.g. the sonars not in their turn; latency: from",
    "  the board's moment of measurement, in synchronised host time, to its arrival here.  A",
    "  /range topic is one sensor_msgs/Range per channel with a value, so it runs at channels x",
    "  the transducer's rate; a /joint_states one per update, all channels in it)",
)


def _summary(seen: _Seen, out: TextIO) -> bool:
    """The summary at the end; True when both boards stayed up, samples flowed, the servo
    moved and the recording holds them."""
    status, mcap = seen.status, seen.mcap
    bags = [str(b) for b in getattr(mcap, "bags", [])]
    print("\nsummary", file=out)
    for line in seen.view.summary():
        print(line, file=out)
    for line in LEGEND:
        print(line, file=out)
    for s in status:
        print(
            f"  board {s['board']}: {s['state']}, {s['frames']} frames, "
            f"{s['bad_checksums']} bad checksums, {s['lost_sifs']} SIFs lost, "
            f"{s['timeouts']} call timeouts, RTT {s['rtt_us']} µs",
            file=out,
        )
    for s in status:
        if "bound_us" in s:
            print(
                f"  clock {s['board']}: {s['sync_state']},"
                f" board clock {s['skew_ppm']:+.2f} ppm,"
                f" bound ±{s['bound_us']} µs, {s['sync_exchanges']} exchanges,"
                f" min RTT {s['sync_min_rtt_us']} µs",
                file=out,
            )
    servo_cmds = sum(s["commands"] for s in status)
    dropped = getattr(mcap, "dropped", 0)
    print(f"  servo commands sent: {servo_cmds}", file=out)
    print(
        f"  recording: {', '.join(bags) or 'nothing'} ({getattr(mcap, 'messages', 0)} "
        f"messages, {dropped} dropped)",
        file=out,
    )
    losses = {
        k: sum(s.get(k, 0) for s in status)
        for k in ("lost_sifs", "bad_sifs", "unknown_sifs", "clock_outliers")
    }
    print(
        "  losses: " + ", ".join(f"{v} {k.replace('_', ' ')}" for k, v in losses.items()),
        file=out,
    )
    print(
        "  publishers: "
        + ", ".join(f"{p['publisher']} {p.get('dropped', 0)} dropped" for p in seen.publishers),
        file=out,
    )
    for line in seen.failures:
        print(f"  ERROR {line}", file=out)
    expected = ["/board_a/quad", "/board_a/servo", "/board_b/dist_ir", "/board_b/dist_us"]
    stats = seen.view.stats
    return (
        not seen.failures
        and bool(bags)
        and all(s["state"] == "up" for s in status)
        and servo_cmds > 0
        and all(n in stats and stats[n].count > 0 for n in expected)
    )
