"""What the daemon costs as boards and rates grow: boards served by ONE other process (``board
--count N``, so on a 2-core machine the host side is what is measured), the daemon in this one
with the bus publisher only and one inline subscriber, 8 int32 channels per update.

    .venv/bin/python bench/bench_scale.py [--seconds 5] [--quick]
    .venv/bin/python bench/bench_scale.py --knee     # where one core stops keeping up

Per scenario: the daemon's CPU (getrusage of this process) per update and in % of a core, the
same in multiples of the bare J2A frame decode of the same frames (the reference, measured in the
same run), latency from the board's stamp to the subscriber (the virtual boards' clock is the
host's CLOCK_MONOTONIC) p50/p99, and lost updates checked by their numbers (every update carries
its counter) plus what the daemon itself counted.  Idle boards: 1 update/s, measured once their
clock sync has settled (12 s after connecting; the probe rate adapts down).  RSS per board: the
daemon's RSS with N boards up minus with none, / N.  Clock exchanges per second per board from
the sessions' counters.

More references, also measured in this run: the daemon's sample path alone (the same frames
handed to connected boards' reading steps, no I/O and no waiting: 1 board with 4 frames per read,
and 64 boards in turn with 1 frame per read, as at 64 x 100/s), which shows how much of the
end-to-end cost is the loop's waking and reading rather than the per-update work; one recv of one
frame from a loopback socket (each update pays it when every read carries one frame); and the
CPU of one timed 2 ms wait (each round of the loop pays it).

``--knee``: only where one core stops keeping up.  The daemon (this process, every thread) is
pinned to one CPU and 64 boards come from ``_blaster.py`` on the other (``board --count`` cannot
make enough); the rate per board rises until fewer updates arrive than were asked, one is lost,
or latency p99 passes 100 ms.  The board process's own CPU is shown, so a row where it, not the
daemon, was the limit would be seen."""

from __future__ import annotations

import argparse
import ctypes
import gc
import os
import resource
import select
import signal
import socket
import subprocess
import sys
import threading
import time
from pathlib import Path

from missing_link.board.runtime import BoardRuntime, Transducer
from missing_link.daemon import Daemon
from missing_link.daemon.config import BoardSpec, Config
from missing_link.j2a import FrameDecoder
from missing_link.topics import Update

CHANNELS = 8


def cpu_s() -> float:
    r = resource.getrusage(resource.RUSAGE_SELF)
    return r.ru_utime + r.ru_stime


def proc_cpu_s(pid: int) -> float:
    """CPU seconds (user + system) another process has used so far (Linux /proc)."""
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def rss_kib() -> int:
    """This process's resident memory after a collection, with the C allocator's free memory
    handed back first (glibc), so what an earlier scenario freed does not count against the
    next one's baseline (measured: -860 KiB "per board" with one board without it)."""
    gc.collect()
    try:
        ctypes.CDLL(None).malloc_trim(0)
    except (OSError, AttributeError):  # not glibc: the figure is noisier, not wrong
        pass
    for line in Path("/proc/self/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1])
    return 0


def bare_decode_us(n: int = 20000) -> float:
    """µs per update to decode the same SIF frames with the bare frame decoder."""
    rt = BoardRuntime("b", "m", "s", epoch="e")
    t = Transducer("signal", 0, "counter", "COUNTER", CHANNELS, "int32_t", -1)
    rt.add_transducer(t)
    frames = []
    for i in range(n):
        for ch in range(CHANNELS):
            rt.record(t, ch, i)
        rt.poll()
        frames.append(rt.take_output())
    data = b"".join(frames)
    chunks = [data[k : k + 4096] for k in range(0, len(data), 4096)]
    best = float("inf")
    for _ in range(5):
        dec = FrameDecoder()
        t0 = time.perf_counter()
        for c in chunks:
            dec.feed(c)
        best = min(best, time.perf_counter() - t0)
    return best / n * 1e6


def sample_path_us(boards: int = 1, per_read: int = 4, n: int = 20000) -> float:
    """µs per update of the daemon's own sample path with real objects and no I/O: frames of a
    counting board handed straight to connected boards' reading steps (decode, clock map,
    Update, bus, one inline subscriber), ``per_read`` frames per read, the boards in turn.  The
    board process is paused meanwhile: a sample of its own, stamped later than the frames,
    would make every frame after it take the per-topic increasing-time nudge (a branch the real
    stream never takes)."""
    proc, urls = start_boards(boards, 1.0)
    try:
        with Daemon(Config(boards=[BoardSpec(u) for u in urls], publishers=["bus"])) as d:
            assert d.wait_until_up(60)
            time.sleep(1.0)
            d.subscribe("/**", Watch(), queue=0)
            readers = []
            for session in d.sessions:
                assert session.board is not None
                readers.append(session.board)
            rt = BoardRuntime("b", "m", "s", epoch="e")
            t = Transducer("signal", 0, "counter", "COUNTER", CHANNELS, "int32_t", -1)
            rt.add_transducer(t)
            os.kill(proc.pid, signal.SIGSTOP)
            try:
                # Stamps after the boards' last samples, 10 µs apart, all in the past when read.
                base = time.monotonic_ns() // 1000
                frames = []
                for i in range(n):
                    for ch in range(CHANNELS):
                        rt.record(t, ch, i, stamp_us=base + i * 10)
                    rt.poll()
                    frames.append(rt.take_output())
                reads = [b"".join(frames[k : k + per_read]) for k in range(0, n, per_read)]
                turns = [(readers[k % boards], data) for k, data in enumerate(reads)]
                time.sleep(max(0.0, (base + n * 10) / 1e6 - time.monotonic()))
                paths = [s.path for s in d.sessions]
                clamps = sum(p.host_time_clamps + p.future_clamps for p in paths)
                t0 = time.thread_time()
                for board, data in turns:
                    board.link.step(data, time.monotonic_ns())
                spent = time.thread_time() - t0
                # (a clamp is a branch the real stream does not take: not the path measured)
                assert sum(p.host_time_clamps + p.future_clamps for p in paths) == clamps
            finally:
                os.kill(proc.pid, signal.SIGCONT)
            return spent / n * 1e6
    finally:
        proc.terminate()
        proc.wait(10)


def one_frame() -> bytes:
    rt = BoardRuntime("b", "m", "s", epoch="e")
    t = Transducer("signal", 0, "counter", "COUNTER", CHANNELS, "int32_t", -1)
    rt.add_transducer(t)
    for ch in range(CHANNELS):
        rt.record(t, ch, 1)
    rt.poll()
    return bytes(rt.take_output())


def recv_floor_us(n: int = 20000) -> float:
    """µs for one recv of one update's frame on a loopback TCP socket (the median): what the
    kernel alone costs per update when each read carries one frame, as with many boards at a
    low rate each (64 x 100/s: ~1 frame per board per gathering window)."""
    frame = one_frame()
    times = []
    with (
        socket.create_server(("127.0.0.1", 0)) as srv,
        socket.create_connection(srv.getsockname()) as tx,
        srv.accept()[0] as rx,
    ):
        for _ in range(n):
            tx.send(frame)
            while not select.select([rx], [], [], 1.0)[0]:
                pass
            t0 = time.perf_counter_ns()
            got = rx.recv(65536)
            times.append(time.perf_counter_ns() - t0)
            assert got == frame
    return sorted(times)[n // 2] / 1000


def wake_floor_us(n: int = 500, wait_s: float = 0.002) -> float:
    """CPU µs (this thread's) of one timed wait of the gathering window's length that ends
    by its timeout: what every round of the I/O loop pays to sleep, before any work."""
    ep = select.epoll()
    try:
        t0 = time.thread_time()
        for _ in range(n):
            ep.poll(wait_s)
        return (time.thread_time() - t0) / n * 1e6
    finally:
        ep.close()


def start_boards(
    n: int, rate: float, blaster_cpu: int | None = None
) -> tuple[subprocess.Popen[str], list[str]]:
    """``n`` virtual rate boards in one other process: ``board --count`` (a runtime pass per
    sample, ~13,000-16,000 updates/s at most here), or with ``blaster_cpu`` the load generator
    ``_blaster.py`` on that CPU (the same runtime for the handshake and calls, samples framed
    in bulk: far more than one daemon core takes)."""
    if blaster_cpu is None:
        cmd = [sys.executable, "-m", "missing_link", "board", "--sim", "rate", "--count", str(n)]
        cmd += ["--rate", str(rate), "--channels", str(CHANNELS), "--listen", "tcp://127.0.0.1:0"]
    else:
        cmd = [sys.executable, str(Path(__file__).with_name("_blaster.py")), "--count", str(n)]
        cmd += ["--rate", str(rate), "--channels", str(CHANNELS), "--cpu", str(blaster_cpu)]
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, text=True)
    assert proc.stdout is not None
    urls = [proc.stdout.readline().split()[1] for _ in range(n)]
    return proc, urls


class Watch:
    """The one subscriber: counts, checks numbering, samples latency (cheap, inline)."""

    def __init__(self) -> None:
        self.count = 0
        self.gaps = 0
        self.last: dict[str, int] = {}
        self.lat: list[float] = []
        self.lock = threading.Lock()

    def __call__(self, u: Update) -> None:
        name = u.topic.name
        v = u.values[0]
        with self.lock:
            self.count += 1
            prev = self.last.get(name)
            if prev is not None and v != prev + 1:
                self.gaps += max(0, v - prev - 1) if v > prev else 1
            self.last[name] = v
            if self.count % 8 == 0:
                self.lat.append(time.monotonic_ns() / 1000 - u.board_us[0])


def scenario(
    n: int, rate: float, seconds: float, blaster_cpu: int | None = None
) -> dict[str, float]:
    proc, urls = start_boards(n, rate, blaster_cpu)
    try:
        rss0 = rss_kib()
        cfg = Config(boards=[BoardSpec(u) for u in urls], publishers=["bus"])
        with Daemon(cfg) as d:
            assert d.wait_until_up(60), [s["error"] for s in d.status() if s["state"] != "up"]
            w = Watch()
            d.subscribe("/**", w, queue=0)
            time.sleep(12.0 if rate <= 1.0 else 2.0)  # bursts after connecting settle
            ex0 = sum(s["sync_exchanges"] for s in d.status())
            with w.lock:
                w.gaps, w.lat, c0 = 0, [], w.count
            lost0 = sum(s["lost_sifs"] for s in d.status())
            cpu0, t0, boards0 = cpu_s(), time.monotonic(), proc_cpu_s(proc.pid)
            time.sleep(seconds)
            cpu1, t1, boards1 = cpu_s(), time.monotonic(), proc_cpu_s(proc.pid)
            with w.lock:
                updates, gaps, lat = w.count - c0, w.gaps, sorted(w.lat)
            status = d.status()
            lost = sum(s["lost_sifs"] for s in status) - lost0
            exchanges = sum(s["sync_exchanges"] for s in status) - ex0
            rss = rss_kib() - rss0
    finally:
        proc.terminate()
        proc.wait(10)
    wall = t1 - t0
    cpu = cpu1 - cpu0

    def pct(q: float) -> float:
        return lat[min(len(lat) - 1, int(q * len(lat)))] if lat else float("nan")

    return {
        "boards": n,
        "rate": rate,
        "updates_s": updates / wall,
        "asked_s": n * rate,
        "core_pct": cpu / wall * 100,
        "boards_core_pct": (boards1 - boards0) / wall * 100,  # the board process's
        "us_per_update": cpu / max(1, updates) * 1e6,
        "p50": pct(0.5),
        "p99": pct(0.99),
        "lost": gaps,
        "lost_counted": lost,
        "rss_kib_per_board": rss / n,
        "probes_s": exchanges / wall / n,
    }


KNEE_RATES = (100.0, 400.0, 800.0, 1200.0, 1600.0, 2000.0, 2500.0)


def knee(seconds: float) -> None:
    """64 boards from the load generator on one CPU, the daemon (this process, every thread)
    on another, the rate per board raised until the daemon's one core no longer keeps up: less
    received than asked, a lost update, or latency p99 over 100 ms (a backlog growing)."""
    cpus = sorted(os.sched_getaffinity(0))
    if len(cpus) < 2:
        sys.exit("bench_scale: --knee needs two CPUs (the daemon on one, the boards on another)")
    os.sched_setaffinity(0, {cpus[0]})  # threads started from now on inherit it
    bare = bare_decode_us()
    print(f"bare J2A frame decode (reference, same run): {bare:.2f} µs per update")
    print(f"daemon on CPU {cpus[0]} only; 64 boards from bench/_blaster.py on CPU {cpus[1]}")
    print()
    print(
        "| updates/s asked | received | daemon % of its core | µs per update | x bare decode | "
        "latency p50 / p99 ms | lost (numbered / counted) | board process % of its core | "
        "keeps up |"
    )
    print("|---|---|---|---|---|---|---|---|---|")
    best = 0.0
    kept = 0.0
    for rate in KNEE_RATES:
        r = scenario(64, rate, seconds, blaster_cpu=cpus[1])
        ok = (
            r["updates_s"] >= 0.99 * r["asked_s"]
            and r["lost"] == 0
            and r["lost_counted"] == 0
            and r["p99"] < 100_000
        )
        best = max(best, r["updates_s"])
        if ok:
            kept = r["updates_s"]
        print(
            f"| {r['asked_s']:,.0f} | {r['updates_s']:,.0f} | {r['core_pct']:.1f} | "
            f"{r['us_per_update']:.1f} | {r['us_per_update'] / bare:.1f} | {r['p50'] / 1000:.2f} / "
            f"{r['p99'] / 1000:.2f} | {r['lost']} / {r['lost_counted']} | "
            f"{r['boards_core_pct']:.0f} | {'yes' if ok else 'no'} |",
            flush=True,
        )
        if not ok:
            break
    print()
    print(
        f"knee: {kept:,.0f} updates/s kept up with on one core; at most {best:,.0f}/s received "
        f"past it (64 boards, {CHANNELS} channels per update)"
    )


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seconds", type=float, default=5.0)
    ap.add_argument("--quick", action="store_true", help="fewer scenarios")
    ap.add_argument(
        "--knee", action="store_true", help="only: 64 boards, the daemon on one core, rising rates"
    )
    a = ap.parse_args()
    if a.knee:
        knee(a.seconds)
        return
    bare = bare_decode_us()
    path = sample_path_us()
    path64 = sample_path_us(64, 1)
    recv = recv_floor_us()
    wake = wake_floor_us()
    runs = [(1, 4000.0), (64, 100.0), (16, 1.0), (64, 1.0)]
    if not a.quick:
        busy = [(1, 500.0), (1, 4000.0), (4, 500.0), (16, 500.0), (64, 100.0), (64, 200.0)]
        runs = [*busy, *runs[2:]]
    print("references and floors, measured in this run:")
    print(f"- bare J2A frame decode: {bare:.2f} µs per update (the reference)")
    print(
        f"- daemon sample path, no I/O, 1 board, 4 frames per read: {path:.2f} µs "
        f"({path / bare:.1f}x)"
    )
    print(
        f"- the same, 64 boards in turn, 1 frame per read: {path64:.2f} µs ({path64 / bare:.1f}x)"
    )
    print(f"- one recv of one frame: {recv:.2f} µs ({recv / bare:.1f}x)")
    print(f"- one 2 ms timed wait, CPU: {wake:.2f} µs ({wake / bare:.1f}x)")
    print(
        f"- floor at 64 boards, 1 frame per read (sample path + recv): {path64 + recv:.2f} µs "
        f"({(path64 + recv) / bare:.1f}x), before any loop work or wake-up"
    )
    print()
    print(
        "| boards | updates/s asked | received | daemon % of a core | µs per update | x bare "
        "decode | latency p50 / p99 ms | lost (numbered / counted) | RSS per board | "
        "probes/s per board |"
    )
    print("|---|---|---|---|---|---|---|---|---|---|")
    for n, rate in runs:
        r = scenario(n, rate, a.seconds)
        idle = rate <= 1.0
        per = f"{r['core_pct'] / n:.2f} % per board" if idle else f"{r['us_per_update']:.1f}"
        mult = "-" if idle else f"{r['us_per_update'] / bare:.1f}"
        print(
            f"| {n} | {r['asked_s']:,.0f} | {r['updates_s']:,.0f} | {r['core_pct']:.1f} | {per} "
            f"| {mult} | {r['p50'] / 1000:.2f} / {r['p99'] / 1000:.2f} | {r['lost']} / "
            f"{r['lost_counted']} | {r['rss_kib_per_board']:.0f} KiB | {r['probes_s']:.1f} |",
            flush=True,
        )


if __name__ == "__main__":
    main()
