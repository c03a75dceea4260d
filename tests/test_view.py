"""The live view never cuts the part of a topic name that tells topics apart (issue 33.8): at
80, 100 and 120 columns, topics that share a long start stay distinct and show their end.  Its
latency is from the sample's synchronised host time, whatever the board's clock (issue 45.3)."""

from __future__ import annotations

import io
import re
from collections.abc import Callable
from typing import Any

import pytest
from rich.console import Console

from missing_link.cli.view import ELLIPSIS, LiveView, TopicStats, TopicTable, fit_names, percentile
from missing_link.daemon import BoardSpec, Config, Daemon
from missing_link.descriptors import Transducer
from missing_link.timesync import NOT_SYNCED
from missing_link.topics import Topic, Update
from missing_link.virtual import make_sim
from missing_link.virtual.clocks import AffineClock

from .helpers import wait_for

Serve = Callable[..., Any]
WIDTHS = (80, 100, 120)


def test_names_that_fit_are_whole() -> None:
    names = ["/board_b/dist_ir", "/board_b/dist_us"]
    assert fit_names(names, 16) == {n: n for n in names}


def test_a_shared_start_is_cut_and_the_end_kept() -> None:
    names = ["/board_b/distance_infrared", "/board_b/distance_ultrasonic", "/board_a/quad"]
    shown = fit_names(names, 14)
    assert shown["/board_b/distance_infrared"] == ELLIPSIS + "ance_infrared"
    assert shown["/board_b/distance_ultrasonic"] == ELLIPSIS + "ce_ultrasonic"
    assert shown["/board_a/quad"] == "/board_a/quad"  # fits: whole
    assert all(len(v) <= 14 for v in shown.values())


def test_names_alike_at_the_end_keep_their_start() -> None:
    names = ["/front_left/distance_infrared", "/front_right/distance_infrared"]
    shown = fit_names(names, 20)
    assert len(set(shown.values())) == 2 and all(len(v) == 20 for v in shown.values())
    assert shown[names[0]].startswith("/front_l") and shown[names[1]].startswith("/front_r")
    assert all(v.endswith("infrared") for v in shown.values())


def test_when_no_cut_tells_names_apart_they_stay_whole() -> None:
    names = ["/abcdef", "/abcdeg"]
    assert fit_names(names, 1) == {n: n for n in names}


ROWS = [
    ("/board_a/quad", "50", "-", "180", "320", "1234 -56"),
    ("/board_a/servo/cmd", "2", "-", "150", "300", "14.17 deg"),
    ("/board_b/dist_ir", "25", "25", "199", "377", " ".join(["812"] * 8) + " mm"),
    ("/board_b/dist_us", "25", "25", "201", "380", " ".join(["1402"] * 12) + " mm"),
    ("/rover_front_ranger_board/distance_infrared", "25", "25", "210", "390", "800 mm"),
    ("/rover_front_ranger_board/distance_ultrasonic", "25", "25", "210", "390", "900 mm"),
    ("/rover_front_ranger_board/distance_infrared_raw", "25", "25", "210", "390", "4095"),
]


def topic_cells(text: str) -> list[str]:
    """The topic column's cells of a drawn topic table (the header left out)."""
    return [m.group(1).strip() for m in re.finditer(r"^│ (.*?) +│", text, re.M)]


@pytest.mark.parametrize("width", WIDTHS)
def test_the_topic_table_keeps_every_topic_distinct_at(width: int) -> None:
    buf = io.StringIO()
    Console(file=buf, width=width).print(TopicTable(ROWS))
    text = buf.getvalue()
    assert max(len(line) for line in text.splitlines()) <= width
    cells = topic_cells(text)
    assert len(cells) == len(ROWS) and len(set(cells)) == len(ROWS)
    for (name, *_), cell in zip(ROWS, cells, strict=True):
        head, _, tail = cell.partition(ELLIPSIS)
        assert name.startswith(head) and name.endswith(tail)
        assert cell.endswith(name[-6:])  # the end, where topics of one board differ, shows
    # the short names are whole at every width; the last values are what gets cut
    assert {"/board_b/dist_ir", "/board_b/dist_us"} <= set(cells)


@pytest.mark.parametrize("width", WIDTHS)
def test_the_live_view_of_a_running_daemon_shows_whole_names_at(serve: Serve, width: int) -> None:
    """A real daemon with a ranger board whose name is long: its dist_ir and dist_us topics."""
    long_name = "rover_front_ranger_board_b"
    server = serve(make_sim("rangers", seed=1, name=long_name))
    cfg = Config(boards=[BoardSpec(server.url)], publishers=["bus"])
    with Daemon(cfg) as daemon:
        assert daemon.wait_until_up(10)
        out = io.StringIO()
        view = LiveView(daemon, out)
        try:
            wanted = {f"/{long_name}/dist_ir", f"/{long_name}/dist_us"}
            assert wait_for(lambda: wanted <= set(view.stats), 10)
            console = Console(file=out, width=width)
            console.print(view.render(1.0, None))
        finally:
            view.close()
    text = out.getvalue()
    assert max(len(line) for line in text.splitlines()) <= width
    table = text[text.index("topic") :]
    cells = topic_cells(table)
    assert len(cells) == len(set(cells)) >= 2
    assert any(c.endswith("dist_ir") for c in cells) and any(c.endswith("dist_us") for c in cells)


class _Daemon:
    """What the view asks of a daemon to collect statistics (a subscription, its offset)."""

    realtime_offset_ns = 1_700_000_000_000_000_000

    def subscribe(self, pattern: str, fn: Callable[[Update], None]) -> Any:
        return self

    def cancel(self) -> None:
        pass


def test_latency_is_from_the_synchronised_host_time_not_the_board_clock() -> None:
    """A board whose clock reads 349 s (a replay, a real board's uptime): the latency is the
    arrival (as a host time) minus the sample's host time; before, it was the arrival on
    CLOCK_MONOTONIC minus the board's stamp.  A sample not yet on a clock map has none."""
    t = Transducer("dist", 1, "sharp", "GP2Y0A02YK", 2, "uint16_t", 0, {"unit": "mm"})
    topic = Topic.for_transducer("/b/dist", "b", t, "missing_link_msgs")
    view = LiveView(_Daemon(), io.StringIO())
    recv = 5_000_000_000  # CLOCK_MONOTONIC ns at arrival
    arrived = recv + _Daemon.realtime_offset_ns
    view.on_update(Update.build(topic=topic, board_us=[349_000_000, 349_001_000],
                                host_ns=[arrived - 2_500_000, arrived - 1_500_000],
                                values=[800, 810], seq=0, lost=0, recv_ns=recv))  # fmt: skip
    view.on_update(Update.build(topic=topic, board_us=[349_002_000, 0], host_ns=[arrived, 0],
                                values=[820, None], seq=1, lost=0, recv_ns=recv,
                                clock_flags=NOT_SYNCED))  # fmt: skip
    st = view.stats["/b/dist"]
    assert list(st.latency_us) == [2500.0, 1500.0]
    assert (st.count, st.missing) == (3, 1)


def test_the_view_of_a_board_with_its_own_clock_shows_its_latency(serve: Serve) -> None:
    """A virtual board whose clock is 349 s ahead of this host's: before, -349 s."""
    server = serve(make_sim("rangers", seed=1, name="far", clock=AffineClock(349e6, 20.0)))
    with Daemon(Config(boards=[BoardSpec(server.url)], publishers=["bus"])) as daemon:
        assert daemon.wait_until_up(10)
        view = LiveView(daemon, io.StringIO())
        try:
            assert wait_for(
                lambda: len(view.stats.get("/far/dist_ir", TopicStats()).latency_us) > 50, 10
            )
        finally:
            view.close()
        lat = view.stats["/far/dist_ir"].latency_us
    p50 = percentile(lat, 0.5)
    assert 0 <= p50 < 1e6, p50  # (µs: the sample's way here, not the board's 349 s head start)


#: board text that rich would read as markup: a tag it cannot close, a hyperlink, blinking
MARKUP_UNITS = ("mm[/]", "[link=https://evil.example]ok[/link]", "[blink]deg[/blink]", "[/]")


@pytest.mark.parametrize("unit", MARKUP_UNITS)
def test_board_text_is_drawn_as_text_never_as_markup(serve: Serve, unit: str) -> None:
    """(issue 43.5: a unit of ``mm[/]`` ended the daemon with rich's MarkupError; ``[link=...]``
    wrote a hyperlink into the terminal, ``[blink]`` made it blink)"""
    from missing_link.board.transducer import Transducer

    rt = make_sim("thesis", seed=1)
    t = Transducer("gauge", 30, "gauge", "test", 1, "int16_t", -1, unit=unit, rate_hz=50)
    rt.add_transducer(t, _Gauge())
    server = serve(rt)
    with Daemon(Config(boards=[BoardSpec(server.url)], publishers=["bus"])) as daemon:
        assert daemon.wait_until_up(10)
        out = io.StringIO()
        view = LiveView(daemon, out)
        try:
            assert wait_for(lambda: "/thesis/gauge" in view.stats, 10)
            console = Console(file=out, width=200, force_terminal=True, color_system="truecolor")
            console.print(view.render(1.0, None))
        finally:
            view.close()
    text = out.getvalue()
    assert "\x1b]8;" not in text  # no hyperlink (OSC 8)
    assert "\x1b[5m" not in text and ";5m" not in text  # no blinking
    assert unit in re.sub(r"\x1b\[[0-9;]*m", "", text)  # the unit as the board wrote it


class _Gauge:
    """A sensor that reports 7 at 50 Hz (its ``rate_hz``)."""

    def set_cb(self, fn: Any) -> None:
        self._cb = fn

    def poll_us(self) -> int:
        return 20_000

    def poll(self, now: int) -> None:
        self._cb(0, 7)
