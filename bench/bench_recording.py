"""What recording for ``missing-link replay`` costs: file size and writer time.

The demo rig's two boards (the virtual boards' own runtimes and drivers: encoder at 1 kHz,
servo, 8 IR rangers, 12 sonars), run on simulated time for ``--seconds``, their SIFs decoded by
the daemon's sample path into exactly the updates the daemon publishes (thesis-format topics and
the standard ones: Range, JointState), and the demo's application commanding the servo on every
encoder update.  The same updates (CDR encoded beforehand) go through the MCAP publisher twice
in the same run: ``replay = false`` (the reference: what a recording was before) and
``replay = true`` (the default: descriptions, configuration, commands and board stamps too).
Reported: the file, bytes per second of recording, the writer's time from the first update to
a closed bag, and what the replay's records take, by kind.

    .venv/bin/python bench/bench_recording.py [--seconds 20]
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
import time
from collections import Counter
from pathlib import Path
from typing import Any

from missing_link.daemon.session.sample_path import SamplePath
from missing_link.descriptors import parse_transds
from missing_link.host.config import parse_keys
from missing_link.j2a import HostConnection, SifReceived
from missing_link.publishers.mcap import McapPublisher
from missing_link.publishers.recover import complete_messages
from missing_link.ros.board_record import BoardDescription
from missing_link.ros.msgs import typestore_for
from missing_link.ros.standard import mappings_for
from missing_link.topics import Topic, Update
from missing_link.virtual import make_sim

SERVO_CMD = "/board_a/servo/cmd"


class _SimClock:
    def __init__(self) -> None:
        self.us = 1_000_000

    def __call__(self) -> int:
        return self.us


def demo_updates(seconds: float) -> tuple[list[tuple[str, Any]], int]:
    """The publisher calls a recording of the demo gets, in order, and the SIFs behind them."""
    clock = _SimClock()
    store = typestore_for("jazzy")
    calls: list[tuple[str, Any]] = []
    boards = []
    sifs = 0
    for sim, name in (("encoder_servo", "board_a"), ("rangers", "board_b")):
        rt = make_sim(sim, seed=1, name=name, clock=clock)
        ts = parse_transds(rt.transds_blob().decode(), name)
        path = SamplePath(lambda u: calls.append(("publish", u)), 0)
        path.name = name
        for t in ts:
            topic = Topic.for_transducer(f"/{name}/{t.name}", name, t, "missing_link_msgs")
            path.topics[t.id] = topic
            calls.append(("add_topic", topic))
            try:
                mappings = mappings_for(t, name, store)
            except ValueError:  # (a mapping these sims cannot feed: as the daemon, none)
                mappings = []
            for m in mappings:
                std = Topic.standard_type(f"/{name}/{t.name}/{m.suffix}", name, t, m.type_name,
                                          store)  # fmt: skip
                path.standard.setdefault(t.id, []).append((std, m))
                calls.append(("add_topic", std))
        calls.append(("describe", BoardDescription.of(name, "pty", [f[0] for f in rt.functions],
                      rt.properties, ts, [f"/{name}/{t.name}" for t in ts])))  # fmt: skip
        keys = parse_keys(rt.config.keys_blob(), name)
        calls.append(("config", (name, keys, {k.name: k.default for k in keys})))
        boards.append((rt, path, HostConnection(), ts))
    servo = boards[0][0].index["a2j_set_servo"]
    servo_topic = boards[0][1].topics[3]
    for step in range(int(seconds * 1000)):  # 1 ms of board time a turn
        clock.us += 1000
        for rt, path, conn, _ts in boards:
            rt.poll()
            _replies, frames = rt.take_frames()
            for ev in conn.receive_data(b"".join(frames), step / 1000):
                if isinstance(ev, SifReceived):
                    sifs += 1
                    n = len(calls)
                    path.on_sif(ev, step / 1000)
                    if rt is boards[0][0] and ev.cmd == 0 and calls[n:]:  # the demo's app
                        count = calls[n][1].values[0]
                        if count is not None:
                            value = max(-127, min(127, int(count) // 64))
                            rt.functions[servo][2](bytes((value & 0xFF,)))
                            calls.append(("command", (SERVO_CMD, servo_topic, value)))
    for kind, arg in calls:  # encoded beforehand: both runs write the same bytes
        if kind == "publish":
            _ = arg.cdr
    return calls, sifs


def record(calls: list[tuple[str, Any]], replay: bool, where: Path) -> tuple[float, Any]:
    pub = McapPublisher({"path": str(where), "replay": replay, "rotate_mb": 0})
    t0 = time.perf_counter()
    stamp = 1_800_000_000 * 10**9
    for kind, arg in calls:
        if kind == "publish":
            pub.publish(arg)
            stamp = arg.stamp_ns
        elif kind == "add_topic":
            pub.add_topic(arg)
        elif kind == "describe":
            pub.board_description(arg)
        elif kind == "config":
            pub.add_config(*arg, None)
        else:
            pub.command_sent(*arg, stamp)
    pub.close()
    elapsed = time.perf_counter() - t0
    assert pub.dropped == 0 and not pub.error, (pub.dropped, pub.error)
    return elapsed, pub


def by_kind(bag: Path) -> Counter[str]:
    """Bytes of message data per kind of record (ours by type, the rest together)."""
    out: Counter[str] = Counter()
    for schema, ch, msg in complete_messages(sorted(bag.glob("*.mcap"))):
        name = schema.name.rsplit("/", 1)[-1]
        if name in ("BoardStamps", "BoardDescription", "BoardConfig"):
            out[name] += len(msg.data)
        elif ch.topic.endswith("/cmd"):
            out["commands"] += len(msg.data)
        else:
            out["samples and the rest"] += len(msg.data)
    return out


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=20.0, help="simulated seconds of the demo")
    args = ap.parse_args()
    print(f"recording for replay, CPython {sys.version.split()[0]}, {os.cpu_count()} cores")
    calls, sifs = demo_updates(args.seconds)
    updates = [a for k, a in calls if k == "publish"]
    thesis = sum(1 for u in updates if isinstance(u, Update) and u.topic.encoder is not None)
    commands = sum(k == "command" for k, _ in calls)
    print(f"the demo rig, {args.seconds:g} s: {sifs} SIFs, {len(updates)} updates "
          f"({thesis} thesis-format), {commands} commands\n")  # fmt: skip
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for replay in (False, True, False, True):  # twice each, interleaved: the load is shared
            elapsed, pub = record(calls, replay, Path(tmp) / f"{replay}{len(rows)}")
            size = sum(f.stat().st_size for f in pub.bags[0].glob("*.mcap"))
            rows.append((replay, elapsed, size, pub.messages, pub.bags[0]))
        print("| recording | messages | file | per second of recording | written in | updates/s |")
        print("|---|---|---|---|---|---|")
        best: dict[bool, tuple[float, int, int]] = {}
        for replay, elapsed, size, messages, _bag in rows:
            if replay not in best or elapsed < best[replay][0]:
                best[replay] = (elapsed, size, messages)
        for replay in (False, True):
            elapsed, size, messages = best[replay]
            label = "replay = true (default)" if replay else "replay = false (reference)"
            per_s = size / args.seconds / 1e3
            print(f"| {label} | {messages:,} | {size / 1e6:.2f} MB | {per_s:.1f} kB/s"
                  f" | {elapsed:.2f} s | {len(updates) / elapsed:,.0f} |")  # fmt: skip
        (e0, s0, _), (e1, s1, _) = best[False], best[True]
        print(f"\nreplay = true: file +{(s1 / s0 - 1) * 100:.1f} %, writer time "
              f"{(e1 / e0 - 1) * 100:+.1f} % (best of two runs each)")  # fmt: skip
        kinds = by_kind(rows[1][4])
        print("\nmessage data by kind (replay = true):")
        for kind, n in kinds.most_common():
            print(f"  {kind:22} {n / 1e3:9.1f} kB  ({n / args.seconds / 1e3:.1f} kB/s)")
        print(f"  stamps per thesis-format sample: {kinds['BoardStamps'] / thesis:.1f} B")
    return 0


if __name__ == "__main__":
    sys.exit(main())
