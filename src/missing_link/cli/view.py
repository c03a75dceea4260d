"""The live view of a running daemon (``missing-link run --view``, ``missing-link demo``).

On a terminal it redraws in place (rich's ``Live``): per board the link state, RTT, clock bound
and every loss counter that is not zero, per topic the rate (and the rate configured on the
board, "off" when it is disabled), the latency from the board's moment
of measurement to the host callback, and the last value with its unit.  Columns appear only
where they apply (servo commands only for boards with actuators).  When the output is not a
terminal it prints a plain block every ``plain_period`` seconds instead.  All times in µs.
"""

from __future__ import annotations

import os
import threading
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any, TextIO

from ..topics import Update


@dataclass
class TopicStats:
    count: int = 0
    missing: int = 0
    unit: str = ""
    scale: Callable[[float], float] | None = None  #: raw -> unit (a descriptor with a scale)
    last: list[object] = field(default_factory=list)
    recent: deque[float] = field(default_factory=lambda: deque(maxlen=5000))
    latency_us: deque[float] = field(default_factory=lambda: deque(maxlen=20000))


def percentile(values: Any, q: float) -> float:
    ordered = sorted(values)
    if not ordered:
        return float("nan")
    return float(ordered[min(len(ordered) - 1, int(q * len(ordered)))])


def _fmt(v: object) -> str:
    if v is None:
        return "-"
    if isinstance(v, float):
        return f"{v:.4g}"
    return str(v)


#: board counters shown when they are not zero (key, label)
LOSSES = (
    ("lost_sifs", "lost SIFs"),
    ("bad_sifs", "bad SIFs"),
    ("unknown_sifs", "unknown SIFs"),
    ("bad_checksums", "bad checksums"),
    ("cut_frames", "cut frames"),
    ("clock_outliers", "clock outliers"),
    ("stale_links", "stale links"),
    ("timeouts", "timeouts"),
)


class LiveView:
    """Collects per-topic statistics from the bus and draws them."""

    def __init__(self, daemon: Any, out: TextIO | None = None, title: str = "missing-link") -> None:
        import sys

        self.daemon = daemon
        self.out = out or sys.stdout
        self.title = title
        self.interactive = self.out.isatty() and os.environ.get("TERM", "dumb") != "dumb"
        self.plain_period = 5.0
        self.stats: dict[str, TopicStats] = {}
        self.lock = threading.Lock()
        self.subscription = daemon.subscribe("/**", self.on_update)

    def on_update(self, u: Update) -> None:
        recv_us = u.recv_ns / 1000
        with self.lock:
            st = self.stats.get(u.topic.name)
            if st is None:
                t = u.topic.transducer
                st = self.stats[u.topic.name] = TopicStats(
                    unit=t.unit or "", scale=t.in_unit if t.scaled else None
                )
            st.last = list(u.values)
            st.recent.append(recv_us)
            for stamp, v in zip(u.board_us, u.values, strict=True):
                if v is None:
                    st.missing += 1
                else:
                    st.count += 1
                    st.latency_us.append(recv_us - stamp)

    # ---- drawing -----------------------------------------------------------------------------
    def render(self, elapsed: float, duration: float | None) -> Any:
        from rich.console import Group
        from rich.table import Table
        from rich.text import Text

        span = f"{elapsed:5.1f} s" + (f" / {duration:.0f} s" if duration else "")
        boards = Table(title=f"{self.title}  {span}", title_justify="left", expand=False)
        status = self.daemon.status()
        with_cmds = any(s["commands"] or s["command_errors"] for s in status) or any(
            t.is_actuator for s in self.daemon.sessions for t in _transducers(s)
        )
        for col in ("board", "state", "RTT µs", "clock ±µs"):
            boards.add_column(col)
        if with_cmds:
            boards.add_column("commands")
        boards.add_column("losses")
        for s in status:
            losses = ", ".join(f"{s[k]} {label}" for k, label in LOSSES if s.get(k))
            state = Text(s["state"], style="green" if s["state"] == "up" else "bold red")
            row = [
                s["board"],
                state,
                "-" if s["rtt_us"] is None else str(s["rtt_us"]),
                "-" if "bound_us" not in s else f"{s['bound_us']:.1f}",
            ]
            if with_cmds:
                row.append(str(s["commands"]) if _has_actuator(self.daemon, s["board"]) else "")
            row.append(losses or "none")
            boards.add_row(*row)
        topics = Table(expand=False)
        configured = _configured_rates(self.daemon)
        for col, justify in (
            ("topic", "left"),
            ("msgs/s", "right"),
            ("set Hz", "right"),
            ("latency p50 µs", "right"),
            ("p99 µs", "right"),
            ("last value", "left"),
        ):
            topics.add_column(col, justify=justify)  # type: ignore[arg-type]
        now_us = time.monotonic_ns() / 1000
        with self.lock:
            for name, st in sorted(self.stats.items()):
                rate = sum(1 for t in st.recent if now_us - t <= 1e6)
                lat = list(st.latency_us)[-1000:]
                scale = st.scale
                if scale is None:
                    last = " ".join(_fmt(v) for v in st.last)
                else:  # in the unit (the servo's raw 20 is 14.17 deg)
                    last = " ".join(_fmt(None if v is None else scale(v)) for v in st.last)  # type: ignore[arg-type]
                topics.add_row(
                    name,
                    str(rate),
                    configured.get(name, "-"),
                    f"{percentile(lat, 0.5):.0f}",
                    f"{percentile(lat, 0.99):.0f}",
                    (last[:40] + (f" {st.unit}" if st.unit else "")),
                )
        pubs = [p for p in self.daemon.publisher_status() if p.get("level") or p.get("dropped")]
        parts: list[Any] = [boards, topics]
        for p in pubs:
            style = "bold red" if p.get("level", 0) >= 2 else "yellow"
            parts.append(
                Text(
                    f"publisher {p['publisher']}: {p.get('message', '')}, "
                    f"{p.get('dropped', 0)} dropped",
                    style=style,
                )
            )
        return Group(*parts)

    def run(self, stop: threading.Event, duration: float | None, refresh: float = 1.0) -> None:
        """Draw until ``stop`` is set, ``duration`` passes or a publisher fails for good."""
        from rich.console import Console

        t0 = time.monotonic()
        console = Console(file=self.out, force_terminal=self.interactive)

        def done() -> bool:
            if duration is not None and time.monotonic() - t0 >= duration:
                return True
            return bool(self.daemon.failures())

        if self.interactive:
            from rich.live import Live

            with Live(console=console, refresh_per_second=4, transient=False) as live:
                while not done() and not stop.wait(refresh):
                    live.update(self.render(time.monotonic() - t0, duration))
                live.update(self.render(time.monotonic() - t0, duration))
            return
        next_plain = t0 + self.plain_period
        while not done() and not stop.wait(refresh):
            if time.monotonic() >= next_plain:
                next_plain += self.plain_period
                console.print(self.render(time.monotonic() - t0, duration))

    def summary(self) -> list[str]:
        lines = []
        with self.lock:
            for name, st in sorted(self.stats.items()):
                lat = st.latency_us
                lines.append(
                    f"  {name:<28}{st.count:8d} samples {st.missing:7d} N/A"
                    f"   latency p50 {percentile(lat, 0.5):5.0f} µs"
                    f"  p99 {percentile(lat, 0.99):6.0f} µs"
                )
        return lines

    def close(self) -> None:
        self.subscription.cancel()


def _configured_rates(daemon: Any) -> dict[str, str]:
    """Topic -> its transducer's configured rate (``rate_hz``), or "off" when disabled."""
    out: dict[str, str] = {}
    for s in daemon.sessions:
        values = s.settings.values
        for topic in list(s.topics.values()) + [std for std, _ in s.path.standard.values()]:
            t = topic.transducer.name
            if values.get(f"{t}.enabled") is False:
                out[topic.name] = "off"
            elif isinstance(values.get(f"{t}.rate_hz"), (int, float)):
                out[topic.name] = f"{values[f'{t}.rate_hz']:g}"
    return out


def _transducers(session: Any) -> list[Any]:
    return [t.transducer for t in session.topics.values()]


def _has_actuator(daemon: Any, board: str) -> bool:
    return any(
        s.name == board and any(t.is_actuator for t in _transducers(s)) for s in daemon.sessions
    )
