"""The board's log (issue 36.2, docs/board-log.md): a log call with levels on the board, each
driver's faults said once and then counted, a budget of lines a second with every dropped line
counted; the log SIF's bytes; and the host's side: the typed line (``Daemon.subscribe_logs``,
``Board.on_log``), the console line, the board's counts in its status, a fault said before the
host came, the web console's ``log``, ``/<board>/log`` in MCAP (read back with the ``mcap``
reader) and ``/rosout`` through Zenoh (a plain zenoh subscriber, decoded by rosbags)."""

from __future__ import annotations

import json
import logging
import struct
import threading
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import pytest
from mcap.reader import make_reader
from rosbags.typesys import Stores, get_types_from_msg, get_typestore

from missing_link.board.config import RuntimeConfig
from missing_link.board.failsafe import Failsafe
from missing_link.board.log import (
    BURST,
    ERROR,
    INFO,
    INTERVAL_US,
    LOG_CMD,
    NO_ANSWER,
    WARN,
    encode_line,
    report,
)
from missing_link.board.runtime import BoardRuntime, Transducer
from missing_link.board.timing import Timing
from missing_link.board.wire import SOS
from missing_link.board.wire import encode_frame as board_frame
from missing_link.daemon import Daemon
from missing_link.daemon.config import BoardSpec, Config
from missing_link.host.board import Board
from missing_link.host.board_log import LogLine, parse_info, parse_line
from missing_link.j2a import SOF, Frame, FrameDecoder, encode_frame
from missing_link.publishers.web_model import ConsoleModel
from missing_link.testing import FakeBoardClock
from missing_link.transport import open_transport

from .helpers import free_port, wait_for

ROOT = Path(__file__).resolve().parent.parent
DOC = ROOT / "docs" / "board-log.md"

# docs/board-log.md's two frames: a driver's fault said once, and a count of dropped lines
FAULT_FRAME = (
    "ed 05 fe 28 4e 61 bc 00 00 00 00 00 1e 07 01 00 00 6e 6f 74 20 61 6e 73 77 65 72 69 6e 67 "
    "20 61 74 20 30 78 32 39 20 28 45 49 4f 29 13"
)
DROPPED_FRAME = "ed 06 fe 0d 80 9f d5 00 00 00 00 00 1e ff 00 e0 03 a9"


def log_frames(rt: BoardRuntime) -> list[Frame]:
    frames = [f for f in FrameDecoder().feed(rt.take_output()) if isinstance(f, Frame)]
    return [f for f in frames if f.opcode == LOG_CMD]


def call(rt: BoardRuntime, name: str, payload: bytes = b"") -> Frame:
    rt.feed(encode_frame(SOF, 1, rt.index[name], payload))
    (reply,) = [f for f in FrameDecoder().feed(rt.take_output()) if isinstance(f, Frame)][:1]
    return reply


class Probe:
    """A part that can be taken away: absent, its driver finds it not answering at every
    measurement (and says so through the board's log, as the real drivers do)."""

    def __init__(self) -> None:
        self.absent = False
        self.flood = 0  # lines to say at once, at the next poll
        self._cb: Callable[..., None] | None = None

    def set_cb(self, fn: Callable[..., None]) -> None:
        self._cb = fn

    def next_due_us(self) -> None:
        return None

    def poll(self, now: int) -> None:
        if self.absent:
            report(self, NO_ANSWER, "not answering at 0x29")
        n, self.flood = self.flood, 0
        for i in range(n):
            self.log.line(INFO, f"line {i}")  # type: ignore[attr-defined]
        if self._cb is not None and not self.absent:
            self._cb(0, 42)


def probe_board(clock: Callable[[], int] | None = None) -> tuple[BoardRuntime, Probe]:
    rt = BoardRuntime("probe_board", "m", "s", epoch="e", clock=clock)
    probe = Probe()
    rt.add_transducer(Transducer("probe", 7, "probe", "P", 1, "uint16_t", 0), probe)
    rt.add_function("a2jLogInfo", rt.log.info)
    return rt, probe


# ---- the board ------------------------------------------------------------------------------
def test_a_fault_is_said_once_then_counted() -> None:
    clock = FakeBoardClock()
    rt, probe = probe_board(clock)
    probe.absent = True
    for _ in range(100):
        clock.us += 10_000
        rt.poll()
    (line,) = log_frames(rt)
    stamp, level, source, kind, dropped = struct.unpack("<QBBBH", line.payload[:13])
    assert (level, source, kind, dropped) == (WARN, 7, NO_ANSWER, 0)
    assert line.payload[13:] == b"not answering at 0x29"
    assert stamp == 1_000_000 + 10_000  # when the driver said it
    info = parse_info(call(rt, "a2jLogInfo").payload)
    assert info.faults == ((7, NO_ANSWER, 100),) and (info.said, info.dropped) == (1, 0)


def test_a_flood_is_bounded_by_the_budget_and_every_dropped_line_counted() -> None:
    clock = FakeBoardClock()
    rt, probe = probe_board(clock)
    probe.flood = 1000
    rt.poll()
    flood = log_frames(rt)
    assert [f.payload[13:] for f in flood] == [f"line {i}".encode() for i in range(BURST)]
    assert rt.log.dropped == 1000 - BURST
    clock.us += INTERVAL_US - 1
    rt.poll()
    assert log_frames(rt) == []  # the budget has no room yet: the count waits
    assert rt.next_deadline_us() == clock.us + 1  # (the firmware wakes for it)
    clock.us += 1
    rt.poll()
    (count,) = log_frames(rt)
    line, source, kind = parse_line(count.payload, "probe_board", {7: "probe"}, 0)
    assert line.dropped == 1000 - BURST and line.level == WARN and (source, kind) == (0xFF, 0)
    assert line.text == "992 log lines dropped on the board (its budget)"
    clock.us += 10 * INTERVAL_US
    rt.poll()
    assert log_frames(rt) == []  # said once
    info = parse_info(call(rt, "a2jLogInfo").payload)
    assert (info.said, info.dropped) == (BURST + 1, 1000 - BURST)


def test_the_documented_bytes_and_what_the_host_makes_of_them() -> None:
    fault = board_frame(
        SOS, 5, LOG_CMD, encode_line(12345678, WARN, 7, NO_ANSWER, 0, "not answering at 0x29 (EIO)")
    )
    dropped = board_frame(SOS, 6, LOG_CMD, encode_line(14_000_000, WARN, 0xFF, 0, 992, ""))
    assert fault.hex(" ") == FAULT_FRAME and dropped.hex(" ") == DROPPED_FRAME
    doc = " ".join(DOC.read_text().split())
    assert FAULT_FRAME in doc and DROPPED_FRAME in doc
    (f,) = FrameDecoder().feed(fault)
    assert isinstance(f, Frame)
    line, _, _ = parse_line(f.payload, "rover", {7: "tof"}, 5)
    assert line == LogLine("rover", WARN, "tof: not answering at 0x29 (EIO)", "tof",
                           "not answering", 12345678, 5, 0)  # fmt: skip


def test_what_a_board_sends_is_cleaned_and_its_levels_made_ros_levels() -> None:
    hostile = encode_line(1, 33, 9, 0, 0, "\x1b[31mred\x1b[0m\nforged line")
    line, _, _ = parse_line(hostile, "b", {}, 0)
    assert line.level == ERROR  # 33: up to the next ROS level
    assert "\x1b" not in line.text and "\n" not in line.text
    assert line.text.startswith("transducer 9: ")
    with pytest.raises(ValueError):
        parse_line(b"\x00" * 12, "b", {}, 0)  # shorter than its head
    with pytest.raises(ValueError):
        parse_info(b"\x00" * 12 + b"\x02" + b"\x00" * 6)  # two faults announced, one there


def test_a_board_without_part_two_sends_no_log_sif() -> None:
    clock = FakeBoardClock()
    rt = BoardRuntime("old", "m", "s", epoch="e", clock=clock, part2=False)
    probe = Probe()
    rt.add_transducer(Transducer("probe", 7, "probe", "P", 1, "uint16_t", 0), probe)
    probe.absent = True
    rt.poll()
    assert log_frames(rt) == []


def original_host_sif(stream: bytes, handlers: dict[int, Callable[[bytes], None]]) -> list[str]:
    """The 2014 C host's receive path for frames that start with 0xED, as its code decides it
    (stefanct/java2arduino-c, j2a.c: ``j2a_receiver_thread``, ``read_packet``,
    ``handle_sif_packet``): unescape, check the checksum, refuse the error opcodes 0xF0, 0xF2,
    0xF3, 0xF4 (``read_packet (SOS) failed``), then call every handler registered for the cmd;
    a cmd without one is freed.  Returns what it printed on stderr."""
    said: list[str] = []
    body = bytearray()
    it = iter(stream[1:])
    for b in it:
        body.append((next(it) + 1) & 0xFF if b == 0x7D else b)
    seq, cmd, n = body[0], body[1], body[2]
    payload, csum = bytes(body[3 : 3 + n]), body[3 + n]
    c = seq ^ ((cmd + 11) & 0xFF) ^ ((n + 97) & 0xFF)
    for x in payload:
        c ^= x
    if c != csum:
        return ["j2a_receiver_thread: read_packet (SOS) failed: 16."]
    if cmd in (0xF0, 0xF2, 0xF3, 0xF4):
        return [f"j2a_receiver_thread: read_packet (SOS) failed: {17 if cmd == 0xF0 else 18}."]
    if cmd in handlers:
        handlers[cmd](payload)
    return said


def test_the_2014_host_ignores_the_log_sif() -> None:
    got: list[bytes] = []
    handlers = {13: got.append}  # the thesis's quad transducer, as its host registered it
    assert original_host_sif(bytes.fromhex(FAULT_FRAME), handlers) == []
    assert got == []  # no handler for 0xFE: freed, nothing said, nothing broken
    quad = bytes.fromhex("ed 00 0d 0a 16 01 91 a1 c6 60 06 00 00 00 f4")  # spec's golden SIF
    assert original_host_sif(quad, handlers) == [] and len(got) == 1
    # (an error opcode as SIF cmd would have been refused: why 0xF0..0xF4 are never one)
    err = board_frame(SOS, 0, 0xF2, b"\x00\x01")
    assert original_host_sif(err, handlers) == [
        "j2a_receiver_thread: read_packet (SOS) failed: 18."
    ]


def test_board_side_errors_are_said_once_at_their_level_and_counted(tmp_path: Path) -> None:
    clock = FakeBoardClock()
    rt = BoardRuntime("b", "m", "s", epoch="e", clock=clock)

    class Motor:
        failsafe_ms = 100

        def set_cb(self, fn: Callable[..., None]) -> None:
            pass

        def command(self, payload: bytes) -> tuple[int, bytes]:
            return 0, b""

        def make_safe(self) -> None:
            raise RuntimeError("driver stuck")

    motor = Transducer("motor", 2, "m", "M", 1, "int8_t", -128, kind="actuator", call="go")
    rt.add_transducer(motor, m := Motor())
    rt.add_function("go", rt.gated(motor, m.command))
    rt.add_function("boom", lambda p: 1 / 0)
    rt.timing = Timing(rt)
    rt.failsafe = Failsafe(rt)

    class Broken:
        def read(self) -> bytes:
            raise OSError("flash worn out")

        def write(self, data: bytes) -> None:
            raise OSError("flash worn out")

    rt.config = RuntimeConfig(rt, Broken())  # unreadable at boot: said once
    rt.add_function("a2jLogInfo", rt.log.info)
    for seq in range(3):  # a function that raises, three times
        rt.feed(encode_frame(SOF, seq, rt.index["boom"]))
    rt.feed(encode_frame(SOF, 9, rt.index["a2jConfigSet"], b"\x01"))  # a save that fails
    rt.feed(encode_frame(SOF, 10, rt.index["go"], b"\x05"))
    clock.us += 200_000  # the host silent beyond failsafe_ms: the motor's make_safe raises
    rt.poll()
    lines = {
        (f.payload[10], f.payload[8]): f.payload[13:].decode() for f in log_frames(rt)
    }  # (kind, level) -> text
    assert lines[(11, WARN)].startswith("configuration storage failed reading: flash")
    assert lines[(7, ERROR)] == "boom raised ZeroDivisionError: division by zero"
    assert lines[(10, ERROR)] == "making it safe raised RuntimeError: driver stuck"
    assert len(lines) == 3  # the save's failure is the same kind as the read's: counted
    faults = {(s, k): n for s, k, n in parse_info(call(rt, "a2jLogInfo").payload).faults}
    assert faults == {(0xFF, 11): 2, (0xFF, 7): 3, (2, 10): 1}


# ---- the host -------------------------------------------------------------------------------
@pytest.fixture
def probed(serve: Any) -> Iterator[tuple[Any, Probe, BoardRuntime]]:
    rt, probe = probe_board()
    yield serve(rt, "tcp://127.0.0.1:0"), probe, rt


def test_board_on_log_gives_typed_lines(probed: tuple[Any, Probe, BoardRuntime]) -> None:
    server, probe, _rt = probed
    board = Board(open_transport(server.url), timeout=2.0)
    try:
        board.handshake()
        got: list[LogLine] = []
        board.on_log(got.append)
        probe.absent = True
        assert wait_for(lambda: got, 10)
    finally:
        board.close()
    (line,) = got
    assert (line.board, line.level_name, line.source, line.kind) == (
        "probe_board", "WARN", "probe", "not answering"
    )  # fmt: skip
    assert line.text == "probe: not answering at 0x29" and abs(line.host_ns - time.time_ns()) < 60e9


def test_the_daemon_says_it_everywhere_and_counts_it(
    probed: tuple[Any, Probe, BoardRuntime], caplog: pytest.LogCaptureFixture
) -> None:
    server, probe, rt = probed
    probe.absent = True  # before any host: said to nobody
    assert wait_for(lambda: rt.log.count(7, NO_ANSWER) > 3, 10)
    web = ConsoleModel()
    cfg = Config(boards=[BoardSpec(server.url)], diagnostics_period=0.2)
    d = Daemon(cfg)
    got: list[LogLine] = []
    d.subscribe_logs(got.append, "probe_board")  # (before it starts: the early line comes
    d.subscribe_logs(web.add_log, queue=0)  # with the connection, maybe before a late subscriber)
    with caplog.at_level(logging.WARNING), d:
        assert d.wait_until_up(10), d.failures()
        assert wait_for(lambda: got, 10)
        (early,) = got
        assert early.earlier and early.level_name == "WARN" and early.source == "probe"
        assert early.text.startswith("probe: not answering (before this host was there; ")
        probe.flood = 100  # said now: a burst, the rest counted, the count said
        assert wait_for(lambda: any(x.dropped for x in got), 10)
        dropped = rt.log.dropped  # (the board's own count)
        assert wait_for(lambda: d.status()[0]["log_dropped"] == dropped, 10)
        status = d.status()[0]
        web.set_status(d.status(), [])
    said = [x for x in got if x.text.startswith("probe: line ")]
    # the burst: 8 lines, 7 when the fault's own line took one less than 250 ms before
    assert BURST - 1 <= len(said) <= BURST
    assert len(said) + sum(x.dropped for x in got) == 100 == len(said) + dropped  # all counted
    assert status["log_info"] == len(said) and status["log_warn"] == 2  # the fault, the count
    assert status["log_faults"].startswith("probe not answering x")
    assert int(status["log_faults"].split(" x")[1]) > 3  # counted on the board since
    assert f"[probe_board] WARN {early.text}" in caplog.text  # the console line (stderr)
    (shown,) = web.snapshot()["boards"]
    assert shown["log"][0] == {"level": "WARN", "text": early.text}  # the web console's shape
    assert len(shown["log"]) == len(got)


def test_mcap_records_the_log_as_foxglove_reads_it(
    probed: tuple[Any, Probe, BoardRuntime], tmp_path: Path
) -> None:
    server, probe, _rt = probed
    cfg = Config(
        boards=[BoardSpec(server.url)],
        publishers=["bus", "mcap"],
        publisher_options={"mcap": {"path": str(tmp_path)}},
    )
    with Daemon(cfg) as d:
        got: list[LogLine] = []
        d.subscribe_logs(got.append)
        assert d.wait_until_up(10)
        probe.absent = True
        assert wait_for(lambda: got, 10)
    (bag,) = [p for p in tmp_path.iterdir() if p.is_dir()]
    (path,) = bag.glob("*.mcap")
    with path.open("rb") as f:
        logs = [
            (schema, channel, message)
            for schema, channel, message in make_reader(f).iter_messages()
            if channel.topic == "/probe_board/log"
        ]
    ((schema, channel, message),) = logs
    assert (schema.name, schema.encoding, channel.message_encoding) == (
        "foxglove_msgs/msg/Log", "ros2msg", "cdr"
    )  # fmt: skip
    store = get_typestore(Stores.ROS2_JAZZY)  # decoded from the file's own schema
    store.register(get_types_from_msg(schema.data.decode(), schema.name))
    msg = store.deserialize_cdr(message.data, schema.name)
    assert (msg.level, msg.name, msg.file, msg.line) == (3, "probe_board", "probe", 0)  # WARNING
    assert msg.message == "probe: not answering at 0x29"
    assert msg.timestamp.sec * 10**9 + msg.timestamp.nanosec == got[0].host_ns == message.log_time


def test_zenoh_rosout_is_rcl_interfaces_log(probed: tuple[Any, Probe, BoardRuntime]) -> None:
    """A plain zenoh session (no missing_link code) hears /rosout and rosbags decodes it."""
    import zenoh

    server, probe, _rt = probed
    port = free_port()
    cfg = Config(
        boards=[BoardSpec(server.url)],
        publishers=["bus", "zenoh"],
        publisher_options={"zenoh": {"listen": [f"tcp/127.0.0.1:{port}"], "connect": []}},
    )
    store = get_typestore(Stores.ROS2_JAZZY)
    key = f"0/rosout/rcl_interfaces::msg::dds_::Log_/{store.hash_rihs01('rcl_interfaces/msg/Log')}"
    heard: list[tuple[str, bytes, bytes]] = []
    ready = threading.Event()
    with Daemon(cfg) as d:
        assert d.wait_until_up(10)
        zc = zenoh.Config()
        zc.insert_json5("mode", json.dumps("peer"))
        zc.insert_json5("connect/endpoints", json.dumps([f"tcp/127.0.0.1:{port}"]))
        zc.insert_json5("scouting/multicast/enabled", "false")
        with zenoh.open(zc) as session:

            def on(s: Any) -> None:
                heard.append((str(s.key_expr), bytes(s.payload), bytes(s.attachment or b"")))
                ready.set()

            sub = session.declare_subscriber("0/rosout/**", on)
            tokens = [str(r.ok.key_expr) for r in session.liveliness().get("@ros2_lv/**") if r.ok]
            probe.absent = True
            assert ready.wait(15)
            sub.undeclare()
    (rosout,) = [t for t in tokens if "/MP/" in t and "%rosout/" in t]
    assert rosout.endswith("/:1:,1000:,:10,0:,,")  # rcl's rosout QoS
    k, payload, att = heard[0]
    assert k == key and len(att) == 33
    msg = store.deserialize_cdr(payload, "rcl_interfaces/msg/Log")
    assert (msg.level, msg.name, msg.function) == (30, "probe_board", "probe")
    assert msg.msg == "probe: not answering at 0x29"
    assert struct.unpack("<q", att[8:16])[0] == msg.stamp.sec * 10**9 + msg.stamp.nanosec


@pytest.mark.slow
@pytest.mark.micropython
def test_the_rover_on_micropython_says_its_absent_tof_once() -> None:
    """The rover board file under real MicroPython, its VL53L0X absent from boot (taken out of
    the simulated world, the board rebooted): one WARN naming tof, counted on since."""
    from .helpers import FirmwareSim

    sim = FirmwareSim(ROOT / "examples" / "boards" / "rover.py")
    try:
        sim.ctl("del WORLD.i2c[(0, 0x29)]; reboot()")
        cfg = Config(boards=[BoardSpec(sim.url, timeout=2.0)], diagnostics_period=0.2)
        with Daemon(cfg) as d:
            got: list[LogLine] = []
            d.subscribe_logs(got.append)
            assert d.wait_until_up(30), d.failures()
            assert wait_for(lambda: "tof not answering x" in d.status()[0]["log_faults"], 10)
            first = int(d.status()[0]["log_faults"].split("tof not answering x")[1].split(";")[0])
            assert wait_for(lambda: sim.ctl("result = rt.log.count(7, 1)") > first + 5, 10)
            time.sleep(0.5)  # (a second line, were there one, would be here by now)
        (tof,) = [x for x in got if x.source == "tof"]
        assert tof.level_name == "WARN" and tof.kind == "not answering"
        assert tof.text.startswith("tof: not answering")
        assert sim.ctl("result = fw.drivers['tof'].bus_errors") > first
    finally:
        sim.close()
