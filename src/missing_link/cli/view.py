"""The live view of a running daemon (``missing-link run --view``, ``missing-link demo``).

On a terminal it redraws in place (rich's ``Live``): per board the link state, RTT, clock bound
and every loss counter that is not zero, per topic the rate (and the rate configured on the
board, "off" when it is disabled), the latency from the board's moment
of measurement to its arrival at the host, and the last value with its unit.  The moment of
measurement is the sample's synchronised host time (the board's stamp through its clock map),
so the latency is right for any board clock, a real board's uptime or a replay's; samples
without a clock map yet (``NOT_SYNCED``) have none and are left out of it.  Columns appear only
where they apply (servo commands only for boards with actuators).  When the output is not a
terminal it prints a plain block every ``plain_period`` seconds instead.  All times in µs.

Every string in the view is drawn as text (rich's ``Text``), never read as rich markup: a
board's unit of ``mm[/]`` ended the daemon (MarkupError) and ``[link=...]`` or ``[blink]`` wrote
hyperlinks and blinking into the terminal (issue 43.5).

At the width it is drawn at, the topic table keeps every topic name whole if it can and cuts
the last value instead; names that still do not fit lose their start, never their end, where
topics of one board differ (:func:`fit_names`: ``/board_b/dist_ir`` and ``/board_b/dist_us``
never look alike).
"""

from __future__ import annotations

import os
import threading
import time
from collections import deque
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, TextIO

from ..timesync.sync import NOT_SYNCED
from ..topics import Update

if TYPE_CHECKING:
    from rich.console import Console, ConsoleOptions, RenderResult


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
        #: CLOCK_REALTIME - CLOCK_MONOTONIC of the daemon: an arrival (monotonic) as a host time
        self.realtime_offset_ns = int(daemon.realtime_offset_ns)
        self.subscription = daemon.subscribe("/**", self.on_update)

    def on_update(self, u: Update) -> None:
        recv_us = u.recv_ns / 1000
        arrived_ns = u.recv_ns + self.realtime_offset_ns  # (as a host time: the samples' clock)
        timed = not u.clock_flags & NOT_SYNCED
        with self.lock:
            st = self.stats.get(u.topic.name)
            if st is None:
                t = u.topic.transducer
                st = self.stats[u.topic.name] = TopicStats(
                    unit=t.unit or "", scale=t.in_unit if t.scaled else None
                )
            st.last = list(u.values)
            st.recent.append(recv_us)
            for host_ns, v in zip(u.host_ns, u.values, strict=True):
                if v is None:
                    st.missing += 1
                else:
                    st.count += 1
                    if timed:
                        st.latency_us.append((arrived_ns - host_ns) / 1000)

    # ---- drawing -----------------------------------------------------------------------------
    def render(self, elapsed: float, duration: float | None) -> Any:
        from rich.console import Group
        from rich.text import Text

        span = f"{elapsed:5.1f} s" + (f" / {duration:.0f} s" if duration else "")
        parts: list[Any] = [self._boards(f"{self.title}  {span}"), TopicTable(self._topic_rows())]
        pubs = [p for p in self.daemon.publisher_status() if p.get("level") or p.get("dropped")]
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

    def _boards(self, title: str) -> Any:
        from rich.table import Table
        from rich.text import Text

        boards = Table(title=Text(title), title_justify="left", expand=False)
        status = self.daemon.status()
        with_cmds = any(s["commands"] or s["command_errors"] for s in status) or any(
            t.is_actuator for s in self.daemon.sessions for t in _transducers(s)
        )
        boards.add_column("board", no_wrap=True)  # (the losses wrap first)
        for col in ("state", "RTT µs", "clock ±µs"):
            boards.add_column(col)
        if with_cmds:
            boards.add_column("commands")
        boards.add_column("losses")
        for s in status:
            losses = ", ".join(f"{s[k]} {label}" for k, label in LOSSES if s.get(k))
            state = Text(str(s["state"]), style="green" if s["state"] == "up" else "bold red")
            row: list[Any] = [
                Text(str(s["board"])),
                state,
                "-" if s["rtt_us"] is None else str(s["rtt_us"]),
                "-" if "bound_us" not in s else f"{s['bound_us']:.1f}",
            ]
            if with_cmds:
                row.append(str(s["commands"]) if _has_actuator(self.daemon, s["board"]) else "")
            row.append(losses or "none")
            boards.add_row(*(Text(c) if isinstance(c, str) else c for c in row))
        return boards

    def _topic_rows(self) -> list[tuple[str, ...]]:
        """Per topic: name, msgs/s, configured rate, latency p50 and p99, last value."""
        configured = _configured_rates(self.daemon)
        now_us = time.monotonic_ns() / 1000
        rows: list[tuple[str, ...]] = []
        with self.lock:
            for name, st in sorted(self.stats.items()):
                rate = sum(1 for t in st.recent if now_us - t <= 1e6)
                lat = list(st.latency_us)[-1000:]
                scale = st.scale
                if scale is None:
                    last = " ".join(_fmt(v) for v in st.last)
                else:  # in the unit (the servo's raw 20 is 14.17 deg)
                    last = " ".join(_fmt(None if v is None else scale(v)) for v in st.last)  # type: ignore[arg-type]
                rows.append(
                    (
                        name,
                        str(rate),
                        configured.get(name, "-"),
                        f"{percentile(lat, 0.5):.0f}",
                        f"{percentile(lat, 0.99):.0f}",
                        last[:40] + (f" {st.unit}" if st.unit else ""),
                    )
                )
        return rows

    def run(self, stop: threading.Event, duration: float | None, refresh: float = 1.0) -> None:
        """Draw until ``stop`` is set, ``duration`` passes or a publisher fails for good."""
        from rich.console import Console

        t0 = time.monotonic()
        # Not a terminal (a pipe, a log file): no width to fit, so nothing is cut.  $COLUMNS
        # describes a terminal, not this file (and readline exports it in any process that
        # loads it, so a child inherits a width that has nothing to do with its output).
        width = None if self.interactive else PLAIN_WIDTH
        console = Console(file=self.out, force_terminal=self.interactive, width=width)

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
        values = s.run_config.values
        for topic in list(s.topics.values()) + [
            std for lst in s.path.standard.values() for std, _ in lst
        ]:
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


ELLIPSIS = "…"


#: the width of the plain (not a terminal) view: wide enough that no value is cut
PLAIN_WIDTH = 200


def fit_names(names: Iterable[str], width: int) -> dict[str, str]:
    """Each name as shown in ``width`` characters.  Whole when it fits; else "…" and as much of
    its end as fits, because the end is where topics differ (``…/dist_ir``, ``…/dist_us``).
    Where the ends would look alike, every long name keeps one more character of its start and
    one less of its end, until no two look the same (``/board_a…dist_ir``,
    ``/board_b…dist_ir``).  If no cut tells them apart, every name is shown whole."""
    unique = sorted(set(names))
    whole = {n: n for n in unique}
    long = [n for n in unique if len(n) > width]
    if not long or width < 2:
        return whole
    keep = width - 1
    for head in range(keep + 1):
        tail = keep - head
        shown = {n: n[:head] + ELLIPSIS + (n[-tail:] if tail else "") for n in long}
        if len(set(shown.values())) == len(long):  # (a name shown whole has no "…")
            return {**whole, **shown}
    return whole


#: the topic table's columns (header, justify); the first is the topic, the last the value
TOPIC_COLUMNS = (
    ("topic", "left"),
    ("msgs/s", "right"),
    ("set Hz", "right"),
    ("latency p50 µs", "right"),
    ("p99 µs", "right"),
    ("last value", "left"),
)


class TopicTable:
    """The topic table, laid out for the width it is drawn at (rich hands it that width): the
    numbers whole, then the topics whole if they fit beside a short last value, else cut by
    :func:`fit_names`; the last value takes what is left and is the one cut short."""

    def __init__(self, rows: list[tuple[str, ...]]) -> None:
        self.rows = rows

    def layout(self, width: int) -> tuple[dict[str, str], int]:
        """(topic -> as shown, the last value's width) for a table ``width`` characters wide."""
        numbers = sum(
            max(len(head), *(len(r[i]) for r in self.rows))
            for i, (head, _) in enumerate(TOPIC_COLUMNS[1:-1], start=1)
        )
        room = width - 3 * len(TOPIC_COLUMNS) - 1 - numbers  # (borders and padding)
        least = len(TOPIC_COLUMNS[-1][0])
        shown = fit_names((r[0] for r in self.rows), max(len("topic"), room - least))
        widest = max((len(v) for v in shown.values()), default=0)
        return shown, max(least, room - max(widest, len("topic")))

    def __rich_console__(self, console: Console, options: ConsoleOptions) -> RenderResult:
        from rich.table import Table
        from rich.text import Text

        shown, last_width = self.layout(options.max_width)
        table = Table(expand=False)
        for head, justify in TOPIC_COLUMNS[:-1]:
            table.add_column(head, justify=justify, no_wrap=True)  # type: ignore[arg-type]
        head = TOPIC_COLUMNS[-1][0]
        table.add_column(head, no_wrap=True, overflow="ellipsis", max_width=last_width)
        for row in self.rows:  # (as text: a board's unit is no markup)
            table.add_row(Text(shown[row[0]]), *(Text(cell) for cell in row[1:]))
        yield table
