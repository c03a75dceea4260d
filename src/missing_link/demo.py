"""``missing-link demo``: a virtual thesis board in its own process over a real pseudo-terminal,
its description, and a live view of its samples; meanwhile the encoder steers the servo by RPC
(the thesis test application).  Ends after ``duration`` seconds or Ctrl-C with a summary; exit
code 0 when samples flowed and the link stayed up."""

from __future__ import annotations

import os
import subprocess
import sys
import threading
import time
from collections import deque
from dataclasses import dataclass, field
from typing import TextIO

from .client import Board
from .errors import MissingLinkError
from .j2a import SifReceived
from .samples import SampleDecoder

REFRESH = 0.5
CONTROL_PERIOD = 0.05


@dataclass
class TopicStats:
    count: int = 0
    missing: int = 0
    last: dict[int, int | float] = field(default_factory=dict)
    recent: deque[float] = field(default_factory=lambda: deque(maxlen=4000))
    latency_us: list[float] = field(default_factory=list)


def percentile(values: list[float], q: float) -> float:
    if not values:
        return float("nan")
    ordered = sorted(values)
    return ordered[min(len(ordered) - 1, int(q * len(ordered)))]


def start_board_process(
    sim: str, seed: int, listen: str = "pty", name: str | None = None, timeout: float = 10.0
) -> tuple[subprocess.Popen[str], str]:
    """Start ``missing-link board`` in a child process; return it and the URL it printed."""
    cmd = [sys.executable, "-m", "missing_link", "board", "--sim", sim, "--seed", str(seed)]
    cmd += ["--listen", listen] + (["--name", name] if name else [])
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    lines: list[str] = []
    reader = threading.Thread(
        target=lambda: lines.append(proc.stdout.readline() if proc.stdout else ""), daemon=True
    )
    reader.start()
    reader.join(timeout)
    line = lines[0] if lines else ""
    if not line.startswith("LISTENING "):
        proc.kill()
        err = proc.stderr.read() if proc.stderr else ""
        raise MissingLinkError(f"virtual board did not start (got {line!r}); stderr: {err.strip()}")
    return proc, line.split(" ", 1)[1].strip()


def stop_process(proc: subprocess.Popen[str]) -> None:
    if proc.poll() is None:
        proc.terminate()
        try:
            proc.wait(5)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait(5)


class LiveView:
    """Per-topic rate, latency and last values; per-board link state and error counters."""

    def __init__(self, board: Board, out: TextIO) -> None:
        self.board = board
        self.out = out
        self.interactive = out.isatty() and os.environ.get("TERM", "dumb") != "dumb"
        self.decoder = SampleDecoder(board.name, board.transducers or [])
        self.stats: dict[str, TopicStats] = {t.name: TopicStats() for t in board.transducers or []}
        self.lock = threading.Lock()
        self.rtt_us: deque[float] = deque(maxlen=200)
        self._last_plain = time.monotonic()  # first plain status after 5 s, once data flows

    def on_sif(self, sif: SifReceived, now: float) -> None:
        # The virtual board's clock is this machine's CLOCK_MONOTONIC, so latency is exact.
        for s in self.decoder.decode(sif, now):
            with self.lock:
                st = self.stats[s.transducer]
                if s.value is None:
                    st.missing += 1
                    continue
                st.count += 1
                st.last[s.channel] = s.value
                st.recent.append(now)
                st.latency_us.append(now * 1e6 - s.board_us)

    def last(self, topic: str, channel: int) -> int | float | None:
        with self.lock:
            return self.stats[topic].last.get(channel) if topic in self.stats else None

    def draw(self, elapsed: float, duration: float) -> None:
        b, now = self.board, time.monotonic()
        d, c = b.conn.decoder.stats, b.conn.stats
        rtt = percentile(list(self.rtt_us), 0.5)
        lines = [
            f"t={elapsed:5.1f}/{duration:.0f} s  board {b.name}: link {'up' if b.alive else 'DOWN'}"
            f"  RPC RTT p50 {rtt:5.0f} us  bad frames {d.bad_checksums + d.bad_escapes}"
            f"  cut {d.cut_frames}  lost SIFs {c.sifs_lost}",
            f"  {'topic':<20}{'rate/s':>7}{'latency p50':>13}  last values",
        ]
        with self.lock:
            for name, st in self.stats.items():
                rate = sum(1 for t in st.recent if now - t <= 1.0)
                lat = percentile(st.latency_us[-500:], 0.5)
                last = " ".join(str(st.last[ch]) for ch in sorted(st.last))
                lines.append(f"  /{b.name}/{name:<12}{rate:7d}{lat:10.0f} us  {last[:56]}")
        if self.interactive:
            self.out.write("\x1b[H\x1b[J" + "\n".join(lines) + "\n")
        elif now - self._last_plain >= 5.0:
            self._last_plain = now
            self.out.write("\n".join(lines) + "\n")
        self.out.flush()

    def summary(self) -> list[str]:
        lines = []
        with self.lock:
            for name, st in self.stats.items():
                lat = st.latency_us
                lines.append(
                    f"  /{self.board.name}/{name:<10}{st.count:8d} samples {st.missing:6d} N/A"
                    f"   latency p50 {percentile(lat, 0.5):6.0f} us"
                    f"  p99 {percentile(lat, 0.99):6.0f} us"
                )
        return lines


def run_demo(duration: float = 15.0, seed: int = 0, out: TextIO = sys.stdout) -> int:
    print("missing-link demo: virtual thesis board in its own process, over a pty", file=out)
    proc, url = start_board_process("thesis", seed)
    servo_cmds = 0
    try:
        with Board.open(url) as board:
            print(f"board {board.name} at {url}", file=out)
            print(f"  functions: {', '.join(board.functions)}", file=out)
            for t in board.transducers or []:
                print(
                    f"  transducer {t.id} {t.name}: {t.model}, {t.chan_count} x {t.dtype},"
                    f" N/A {t.na}",
                    file=out,
                )
            view = LiveView(board, out)
            board.on_sif(None, view.on_sif)
            t0 = next_draw = time.monotonic()
            interrupted = False
            try:
                while time.monotonic() - t0 < duration and board.alive:
                    # The thesis test application: encoder count -> proportional servo deflection.
                    count = view.last("quad", 0)
                    if count is not None:
                        deflection = max(-127, min(127, int(count) // 64))
                        t1 = time.monotonic()
                        board.call_ok(
                            "a2j_set_servo", deflection.to_bytes(1, "little", signed=True)
                        )
                        view.rtt_us.append((time.monotonic() - t1) * 1e6)
                        servo_cmds += 1
                    if time.monotonic() >= next_draw:
                        view.draw(time.monotonic() - t0, duration)
                        next_draw += REFRESH
                    time.sleep(CONTROL_PERIOD)
            except KeyboardInterrupt:
                interrupted = True
            alive = board.alive
            d, c = board.conn.decoder.stats, board.conn.stats
            print("\nsummary", file=out)
            for line in view.summary():
                print(line, file=out)
            print(
                f"  link: {d.frames} frames, {d.bad_checksums} bad checksums, "
                f"{c.sifs_lost} SIFs lost, {c.timeouts} call timeouts",
                file=out,
            )
            print(f"  servo commands sent: {servo_cmds}", file=out)
            flowed = sum(st.count for st in view.stats.values()) > 0
    except MissingLinkError as e:
        print(f"demo FAILED: {e}", file=out)
        return 1
    finally:
        stop_process(proc)
    ok = alive and flowed and servo_cmds > 0
    print("demo " + ("interrupted" if interrupted else "finished OK" if ok else "FAILED"), file=out)
    return 130 if interrupted else 0 if ok else 1
