"""The daemon's sample path, measured.

1. Latency, board's moment of measurement -> subscriber callback: a virtual board in another
   process over a real pty, one transducer at 100 Hz and at 1 kHz.  The virtual board's clock is
   the host's CLOCK_MONOTONIC, so the truth is known.  Reference (same run): the raw one-way
   latency of the same kind of pty between two processes (half a raw echo round trip).
2. Throughput on one core: SIF frames (8 x uint16 per SIF, as the IR board sends) decoded into
   samples and published on the bus to one subscriber.  Reference: the bare frame decoder on the
   same bytes.
3. MCAP write rate: thesis-format messages through the mcap publisher (queue + writer thread) to
   a finished rosbag2 directory.  Reference: rosbags' Writer called directly with the same bytes.

    .venv/bin/python bench/bench_daemon.py [--seconds 5]
"""

from __future__ import annotations

import argparse
import itertools
import os
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

from _patch import replace
from bench_rpc import raw_echo_rate
from missing_link.board.runtime import BoardRuntime, Transducer
from missing_link.cli.view import percentile
from missing_link.daemon import BoardSession, Daemon
from missing_link.daemon.config import BoardSpec, Config
from missing_link.descriptors import parse_transds
from missing_link.j2a import SOF, FrameDecoder, HostConnection, SifReceived, encode_frame
from missing_link.publishers.mcap import McapPublisher
from missing_link.topics import Topic, Update
from missing_link.virtual.process import start_board_process, stop_process


def latency(rate_hz: float, seconds: float) -> tuple[int, float, float, float, int]:
    proc, url = start_board_process("rate", 0, "pty", extra=["--rate", str(rate_hz)])
    lat: list[float] = []
    try:
        with Daemon(Config(boards=[BoardSpec(url)])) as d:
            assert d.wait_until_up(10)

            def on_update(u: Update) -> None:
                lat.append(time.monotonic_ns() / 1000 - u.board_us[0])

            d.subscribe("/rate/signal", on_update, queue=0)  # inline, as the README rows
            time.sleep(seconds)
            lost = d.status()[0]["lost_sifs"]
    finally:
        stop_process(proc)
    lat = lat[int(rate_hz) // 2 :]  # drop the first half second
    return len(lat), percentile(lat, 0.5), percentile(lat, 0.99), max(lat), lost


class _Drv:
    def set_cb(self, fn: object) -> None:
        self.fn = fn


def sif_stream(count: int) -> tuple[bytes, Transducer]:
    clock = iter(range(10**6, 10**12, 997))
    rt = BoardRuntime("b", "m", "s", epoch="e", clock=lambda: next(clock))
    t = Transducer("dist_ir", 1, "sharp", "GP2Y0A02YK", 8, "uint16_t", 0, unit="mm")
    drv = _Drv()
    rt.add_transducer(t, drv)
    chunks = []
    for i in range(count):
        for ch in range(8):
            drv.fn(ch, 200 + (i * 7 + ch * 13) % 1300)  # type: ignore[attr-defined]
        rt.poll()
        chunks.append(rt.take_output())
    return b"".join(chunks), t


def sustained(rate_hz: float, channels: int, seconds: float) -> tuple[float, int, int]:
    """End to end over a pty: samples/s delivered, counter gaps (lost updates), lost SIFs.
    The counter sim numbers its updates, so a gap anywhere on the path shows."""
    proc, url = start_board_process(
        "rate", 0, "pty", extra=["--rate", str(rate_hz), "--channels", str(channels)]
    )
    seen: list[int] = []
    try:
        with Daemon(Config(boards=[BoardSpec(url)])) as d:
            assert d.wait_until_up(10)
            time.sleep(0.5)
            d.subscribe("/rate/signal", lambda u: seen.append(u.values[0]), queue=0)
            t0 = time.monotonic()
            time.sleep(seconds)
            n = len(seen)
            elapsed = time.monotonic() - t0
            lost = d.status()[0]["lost_sifs"]
    finally:
        stop_process(proc)
    window = seen[:n]
    gaps = sum(b - a - 1 for a, b in itertools.pairwise(window) if b > a + 1)
    return n * channels / elapsed, gaps, lost


def throughput(seconds: float) -> tuple[float, float]:
    stream, bt = sif_stream(20_000)
    (t,) = parse_transds("transds/1\n" + bt.descriptor_line() + "\n")
    pieces = [stream[i : i + 4096] for i in range(0, len(stream), 4096)]
    daemon = Daemon(Config())
    ctx = daemon.session_context()
    session = BoardSession(ctx, BoardSpec("memory://bench"))
    topic = Topic.for_transducer("/b/dist_ir", "b", t, "missing_link_msgs")
    replace(session.path, "topics", {t.id: topic})  # (the session's own table, as at connect)
    ctx.faces.declare(topic)
    got = [0]
    daemon.subscribe("/b/dist_ir", lambda u: got.__setitem__(0, got[0] + 8), queue=0)

    def full() -> int:
        conn = HostConnection()
        now = time.monotonic()
        for p in pieces:
            for ev in conn.receive_data(p, now):
                if isinstance(ev, SifReceived):
                    session.path.on_sif(ev, now)
        return 20_000 * 8

    def bare() -> int:
        dec = FrameDecoder()
        for p in pieces:
            dec.feed(p)
        return 20_000 * 8

    def rate(fn: object) -> float:
        done, t0 = 0, time.perf_counter()
        while time.perf_counter() - t0 < seconds:
            done += fn()  # type: ignore[operator]
        return done / (time.perf_counter() - t0)

    ours = rate(full)
    assert got[0] > 0
    return ours, rate(bare)


def mcap_rate(n: int) -> tuple[float, float, float]:
    (t,) = parse_transds("transds/1\ndist_ir,1,sharp,GP2Y0A02YK,8,uint16_t,0,unit=mm\n")
    topic = Topic.for_transducer("/b/dist_ir", "b", t, "missing_link_msgs")
    updates = [
        Update.build(
            topic=topic,
            board_us=[i] * 8,
            host_ns=[10**18 + i * 1000] * 8,
            values=[500 + i % 100] * 8,
            seq=i & 0xFF,
            lost=0,
            recv_ns=i,
        )
        for i in range(n)
    ]
    with tempfile.TemporaryDirectory() as tmp:
        pub = McapPublisher({"path": tmp, "rotate_mb": 0})
        pub.add_topic(topic)
        t0 = time.perf_counter()
        for u in updates:
            pub.publish(u)
        pub.close()
        ours = n / (time.perf_counter() - t0)
        assert pub.messages_by_topic[topic.name] == n and pub.dropped == 0
        size = sum(f.stat().st_size for f in Path(tmp).rglob("*.mcap"))
        from rosbags.rosbag2 import StoragePlugin, Writer

        w = Writer(Path(tmp) / "ref", version=9, storage_plugin=StoragePlugin.MCAP)
        w.open()
        conn = w.add_connection(topic.name, topic.type_name, typestore=pub.typestore)
        datas = [u.cdr for u in updates]
        t0 = time.perf_counter()
        for i, data in enumerate(datas):
            w.write(conn, 10**18 + i, data)
        w.close()
        ref = n / (time.perf_counter() - t0)
    return ours, ref, size / n


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=5.0, help="per latency run")
    args = ap.parse_args()
    print(f"missing-link sample path, CPython {sys.version.split()[0]}, {os.cpu_count()} cores")
    _raw_rate, raw_rtt = raw_echo_rate("pty", encode_frame(SOF, 0, 0, bytes(12)), 2.0)
    print("\n1. latency: board measurement -> subscriber callback, board process over a pty")
    print(
        f"{'rate':>7} | {'samples':>8} {'p50':>8} {'p99':>8} {'max':>8} {'lost SIFs':>9}"
        " | ref: raw pty one-way p50"
    )
    for hz in (100, 1000):
        n, p50, p99, mx, lost = latency(hz, args.seconds)
        print(
            f"{hz:>5}Hz | {n:>8} {p50:>6.0f}us {p99:>6.0f}us {mx:>6.0f}us {lost:>9}"
            f" | {raw_rtt / 2:.0f} us"
        )
    print("\n2a. sustained end to end over a pty, 8 x int32 per SIF (board process included)")
    print(f"{'SIFs/s asked':>12} | {'samples/s got':>13} {'gaps':>6} {'lost SIFs':>9}")
    for hz in (2000, 8000, 16000, 32000):
        got, gaps, lost = sustained(hz, 8, 3.0)
        print(f"{hz:>12} | {got:>13,.0f} {gaps:>6} {lost:>9}")
    print("\n2b. decode + publish on one core (8 x uint16 per SIF, one bus subscriber)")
    ours, bare = throughput(2.0)
    print(
        f"   samples/s decoded and published: {ours:,.0f}"
        f"   (reference, frame decode only: {bare:,.0f})"
    )
    print(
        "\n3. MCAP recording (rosbag2 + MCAP, 8 x uint16 thesis-format messages; ours includes"
        " CDR encoding, the reference writes pre-encoded bytes)"
    )
    ours_m, ref_m, per = mcap_rate(50_000)
    print(
        f"   messages/s through the mcap publisher: {ours_m:,.0f}   "
        f"(reference, rosbags Writer direct: {ref_m:,.0f}); {per:.0f} bytes/message on disk"
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
